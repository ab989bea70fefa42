"""``cellsim export``: a recorded run as MCAP, for Foxglove."""

from __future__ import annotations

from pathlib import Path

from cellsim.cli.common import EXIT_OK, InputError


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "export",
        help="write a recorded run as MCAP for Foxglove (every channel, the arms' frames, the cell in 3D)",
        description="Write a run's black box as an MCAP file: every channel module.signal as the JSON topic "
        "/module/signal with its schema (one message per black-box message, at its simulated time), the robots' links "
        "as foxglove.FrameTransforms on /tf, and fixtures, sensor volumes, arms and people as foxglove.SceneUpdate on "
        "/scene. Open it in Foxglove to plot any channel and watch the cell in 3D. Exits 0, or 2 on a missing or "
        "corrupt run (nothing written).",
    )
    p.add_argument("run", type=Path, metavar="RUN", help="run folder (as written by simulate) or its blackbox.sqlite")
    p.add_argument("--mcap", type=Path, required=True, metavar="FILE", help="the MCAP file to write (replaced if it exists)")
    p.set_defaults(handler=run)


def run(args) -> int:
    from cellsim.foxglove import ExportError, export_mcap

    try:
        done = export_mcap(args.run, args.mcap)
    except ExportError as e:
        raise InputError(str(e)) from None
    print(f"{done.path}: {done.messages:,} messages of {done.channels} channels, {done.frames:,} moments in 3D (/tf, /scene)")
    return EXIT_OK
