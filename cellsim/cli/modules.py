"""``cellsim modules``: list the module kinds a scenario can use, or describe one."""

from __future__ import annotations

import sys

from cellsim.cli.common import EXIT_OK, InputError


def add_parser(subparsers) -> None:
    mods = subparsers.add_parser(
        "modules",
        help="list the module kinds a scenario can use, or describe one",
        description="Without KIND: every module kind (cellsim's and installed plug-ins'), its section and what it "
        "is. With KIND: its parameters (type, default, meaning), channels (outputs), inputs others drive, "
        "physical-sample and command fields. "
        "Generated from the code's own declarations.",
    )
    mods.add_argument("kind", nargs="?", help="a kind to describe in full, e.g. robot")
    mods.add_argument("--json", action="store_true", help="print as JSON on standard output")
    mods.set_defaults(handler=run)


def run(args) -> int:
    import json

    from rich.console import Console
    from rich.markup import escape as e
    from rich.table import Table

    from cellsim import kinds_doc, registry

    console = Console()
    if args.kind is None:
        kinds, errors = kinds_doc.catalogue()
        if args.json:
            json.dump({"kinds": kinds, "errors": errors}, sys.stdout, indent=2)
            sys.stdout.write("\n")
        else:
            table = Table(title="Module kinds (cellsim modules KIND for one in full)", title_justify="left")
            for column in ("kind", "section", "what it is"):
                table.add_column(column, style="bold" if column == "kind" else None, overflow="fold")
            for k in kinds:
                table.add_row(e(k["kind"]), k["section"], e(k["summary"]))
            console.print(table)
            for error in errors:
                console.print(f"[yellow]not available: {e(error)}[/yellow]")
        return EXIT_OK
    try:
        info = kinds_doc.describe(args.kind)
    except registry.KindError as error:
        from cellsim.config.typed_yaml import suggest

        known = registry.kind_names()
        raise InputError(f"{error}" + (suggest(args.kind, known) or f" (known: {', '.join(known)})")) from None
    if args.json:
        json.dump(info, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return EXIT_OK
    console.print(f"[bold]{e(info['kind'])}[/bold] ({info['section']}): {e(info['summary'])}")
    params = Table(title="parameters", title_justify="left")
    for column in ("name", "type", "default", "valid range", "meaning"):  # folded, never cut: keys are long
        params.add_column(column, style="bold" if column == "name" else None, overflow="fold")
    for p in info["parameters"]:
        params.add_row(e(p["name"]), e(p["type"]), e(p["default"]), e(p["range"]), e(p["doc"]))
    console.print(params)
    if info["channels"]:
        channels = Table(title=f"channels ({info['kind']} module NAME publishes NAME.signal)", title_justify="left")
        for column in ("signal", "type", "meaning"):
            channels.add_column(column, style="bold" if column == "signal" else None, overflow="fold")
        for c in info["channels"]:
            channels.add_row(e(c["signal"]), e(c["type"]), e(c["meaning"]))
        console.print(channels)
    if info["inputs"]:
        inputs = Table(title="inputs (driven as NAME.input, e.g. by a safety controller's commands)", title_justify="left")
        for column in ("input", "type", "meaning"):
            inputs.add_column(column, style="bold" if column == "input" else None, overflow="fold")
        for i in info["inputs"]:
            inputs.add_row(e(i["input"]), e(i["type"]), e(i["meaning"]))
        console.print(inputs)
    if info["physical_sample_fields"]:
        console.print("physical sample fields (shadow and twin mode): " + e(", ".join(info["physical_sample_fields"])))
    if info["command_fields"]:
        console.print("command fields (sent to the physical twin in twin mode): " + e(", ".join(info["command_fields"])))
    if info["files"]:
        console.print("file parameters (relative to the scenario): " + e(", ".join(info["files"])))
    return EXIT_OK
