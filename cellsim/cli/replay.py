"""``cellsim replay``: play a recorded run in Meshcat (a browser), with a time slider."""

from __future__ import annotations

from pathlib import Path

from cellsim.cli.common import InputError, _terminate_as_interrupt


def add_parser(subparsers) -> None:
    rep = subparsers.add_parser(
        "replay",
        help="play a recorded run in Meshcat (a browser), with a time slider",
        description="Rebuild the run's cell from its scenario.yaml and play its black box into a Meshcat recording: "
        "the robot's joints, the people, the light curtain, safety modes and scanner fields as recorded. Prints the "
        "Meshcat URL (localhost only), then serves until Enter on a terminal (exit 0), or Ctrl-C or SIGTERM (exit 130).",
    )
    rep.add_argument("run", type=Path, metavar="RUN", help="run folder (as written by simulate) or its blackbox.sqlite")
    rep.add_argument("--meshcat", action="store_true", help="play it in Meshcat (required: the browser player)")
    rep.add_argument(
        "--at", type=float, default=0.0, metavar="T",
        help="start the animation at T seconds of the run (default 0); the animation's time 0 is then T",
    )
    rep.add_argument("--speed", type=float, default=1.0, help="times real time (0.01 to 100, default 1)")
    rep.set_defaults(handler=run)


def run(args) -> int:
    from cellsim.visual.serve import cmd_replay as replay

    with _terminate_as_interrupt():  # from the start: a SIGTERM right after the URL is printed ends it as Ctrl-C does
        return replay(args, InputError)
