"""``cellsim scenario export`` and ``cellsim scenario check``: inspect scenario files."""

from __future__ import annotations

import sys
from pathlib import Path

from cellsim.cli.common import EXIT_OK, _add_set, _load


def add_parser(subparsers) -> None:
    scenario = subparsers.add_parser("scenario", help="inspect scenario files", description="Inspect scenario files.")
    ssub = scenario.add_subparsers(metavar="ACTION", dest="_action")
    scenario.set_defaults(handler=lambda args: _usage(scenario))
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


def _usage(parser) -> int:
    """``cellsim scenario`` without an action: its own usage, on stderr, as a usage error."""
    from cellsim.cli.common import EXIT_INPUT

    parser.print_help(sys.stderr)
    return EXIT_INPUT


def run_export(args) -> int:
    from cellsim import api

    sf = _load(args)
    if args.out is None:
        sys.stdout.write(api.scenario_yaml(sf))
    else:
        api.save_scenario(sf, args.out)
    return EXIT_OK


def run_check(args) -> int:
    from cellsim import api

    sf = _load(args)
    case = api.compile_conditions(sf)  # builds and wires the diagram, then compiles the formulas
    defaults = [name for name in api.default_conditions(sf) if name in case.conditions]
    print(
        f"{args.scenario}: ok ({len(case.conditions)} safety conditions, {len(case.use_cases)} use cases, "
        f"{len(sf.scenario.validation.coverage)} coverage criteria)"
    )
    if defaults:
        print(f"default conditions: {', '.join(defaults)}")
    for name, reason in sf.scenario.validation.waive.items():
        print(f"waived: {name} ({reason})")
    return EXIT_OK
