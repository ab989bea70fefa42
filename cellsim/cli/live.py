"""``cellsim live``: run the twin in real time beside the real cell, on Zenoh."""

from __future__ import annotations

import sys
from pathlib import Path

from cellsim.cli.common import EXIT_FINDING, EXIT_OK, InputError, _add_live_args, _live_run


def add_parser(subparsers) -> None:
    live = subparsers.add_parser(
        "live",
        help="run the twin in real time beside the real cell, on Zenoh",
        description="Run the scenario's twin paced to the wall clock. Entities in shadow or twin mode "
        "take their physical samples from Zenoh (cellsim/<cell>/physical/<entity>); commands of entities in "
        "twin mode are published (cellsim/<cell>/command/<entity>); every channel is published "
        "(cellsim/<cell>/twin/...). `cellsim twin-mode` switches an entity while it runs. The black box "
        "is recorded as in any run. Key space and formats: docs/live.md. By default it listens on "
        "tls/127.0.0.1:7447 with multicast scouting off, as the twin role: every other process must show a "
        "certificate of the cell's CA, and may do only what its role allows (docs/security.md).",
    )
    live.add_argument("scenario", type=Path, help="scenario YAML file")
    _add_live_args(live, duration_default="until interrupted")
    live.add_argument(
        "--wait-physical", type=float, default=10.0, metavar="SECONDS",
        help="before starting the clock, wait this long at most for samples of every entity in shadow or twin mode (default 10)",
    )
    live.add_argument(
        "--foxglove", type=int, nargs="?", const=8765, default=None, metavar="PORT",
        help="also serve the twin on Foxglove's WebSocket (ws://127.0.0.1:PORT, default port 8765; 0: any free "
        "port): every channel, the arms' frames (/tf) and the cell in 3D (/scene), as `cellsim export --mcap` writes",
    )
    live.add_argument("--foxglove-host", default="127.0.0.1", metavar="HOST",
                      help="address the Foxglove server listens on (default loopback only)")
    live.set_defaults(handler=run)


def run(args) -> int:
    from cellsim import api

    feed = None

    def check(sf):
        nonlocal feed
        if not 0.0 <= args.wait_physical <= 3600.0:
            raise InputError(f"--wait-physical {args.wait_physical:g}: expected 0 to 3600 seconds")
        if args.foxglove is not None and not 0 <= args.foxglove <= 65535:
            raise InputError(f"--foxglove {args.foxglove}: expected a port from 0 to 65535")
        if args.foxglove is not None:  # bound before the session opens and anything is said or written
            try:
                feed = api.FoxgloveFeed(args.foxglove_host, args.foxglove, f"cellsim {sf.scenario.name}")
            except Exception as e:  # noqa: BLE001 - the SDK raises its own errors for a port in use
                raise InputError(f"--foxglove {args.foxglove}: cannot serve on {args.foxglove_host}: {e}") from None

    def twin(sf, out, session, duration):
        if not args.quiet:
            print(f"cellsim live: {sf.scenario.name} twin running, recording to {out}", file=sys.stderr)
        if feed is not None:  # said even with --quiet: the port (of 0, any free one) is what a viewer needs
            print(f"cellsim live: Foxglove on ws://{args.foxglove_host}:{feed.port}", file=sys.stderr, flush=True)
        run = api.simulate(sf, out, io=api.Live(session, args.wait_physical, foxglove=feed), seed=args.seed,
                           duration=duration, check=False)
        return EXIT_FINDING if run.summary.mishap else EXIT_OK

    try:
        return _live_run(args, "twin", True, twin, check)
    finally:
        if feed is not None:
            feed.close()
