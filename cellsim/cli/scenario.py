"""``cellsim scenario export`` and ``cellsim scenario check``: inspect scenario files."""

from __future__ import annotations

import sys
from pathlib import Path

from cellsim.cli.common import EXIT_OK, _add_set, _load


def add_parser(subparsers) -> None:
    scenario = subparsers.add_parser("scenario", help="inspect scenario files", description="Inspect scenario files.")
    ssub = scenario.add_subparsers(metavar="ACTION")
    export = ssub.add_parser(
        "export",
        help="print the fully resolved scenario as YAML",
        description="Load a scenario, apply --set overrides, and write it back with every default "
        "filled in. Loading the export gives the same scenario.",
    )
    export.add_argument("scenario", type=Path, help="scenario YAML file")
    _add_set(export)
    export.add_argument("--out", type=Path, help="write to this file instead of standard output")
    export.set_defaults(handler=run_export)
    check = ssub.add_parser(
        "check",
        help="check a scenario without running it",
        description="Load and wire a scenario and compile its safety conditions; report the first problem.",
    )
    check.add_argument("scenario", type=Path, help="scenario YAML file")
    _add_set(check)
    check.set_defaults(handler=run_check)


def run_export(args) -> int:
    from cellsim.scenario import export_scenario

    sf = _load(args)
    if args.out is None:
        sys.stdout.write(export_scenario(sf))
    else:
        from cellsim.atomic import write_text

        write_text(args.out, export_scenario(sf, destination_dir=args.out.resolve().parent))
    return EXIT_OK


def run_check(args) -> int:
    from cellsim.validation.check import scenario_safety_case

    sf = _load(args)
    case = scenario_safety_case(sf)  # builds and wires the diagram, then compiles the formulas
    from cellsim.validation.defaults import default_conditions

    defaults = [name for name in default_conditions(sf.scenario) if name in case.conditions]
    print(
        f"{args.scenario}: ok ({len(case.conditions)} safety conditions, {len(case.use_cases)} use cases, "
        f"{len(sf.scenario.validation.coverage)} coverage criteria)"
    )
    if defaults:
        print(f"default conditions: {', '.join(defaults)}")
    for name, reason in sf.scenario.validation.waive.items():
        print(f"waived: {name} ({reason})")
    return EXIT_OK
