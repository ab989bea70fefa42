"""``cellsim dashboard``: watch the cell in operation in the terminal (the running twin, or a recorded run)."""

from __future__ import annotations

from pathlib import Path

from cellsim.cli.common import EXIT_OK, InputError, _add_network_args


def add_parser(subparsers) -> None:
    dash = subparsers.add_parser(
        "dashboard",
        help="watch the cell in operation in the terminal (the running twin, or a recorded run)",
        description="A terminal dashboard of the running twin (found on the network, or --cell) or, with --replay, "
        "of a recorded run: safety modes, hazards, every entity's twin mode and link health with twin and physical "
        "values side by side, the robot, the safety conditions over the trace so far, the bridge daemon's "
        "diagnostics and an event log. Keys: m switches an entity's twin mode (with a confirmation), q quits.",
    )
    dash.add_argument("--cell", default=None, help="the running twin's cell (default: the first twin that answers)")
    dash.add_argument("--replay", type=Path, metavar="RUN", help="play a recorded run (a run folder or black box) instead")
    dash.add_argument("--speed", type=float, default=1.0, help="with --replay: times real time (default 1)")
    dash.add_argument("--start", type=float, default=0.0, help="with --replay: the simulated time to start from (s)")
    _add_network_args(dash)
    dash.add_argument("--role", choices=("observer", "engineer"), default="observer",
                      help="whose certificate to connect with: an observer watches; an engineer may also switch "
                      "twin modes (default: observer)")
    dash.set_defaults(handler=run)


def run(args) -> int:
    import math

    from cellsim.dashboard.app import Dashboard
    from cellsim.dashboard.feeds import LiveFeed, ReplayFeed

    if not (math.isfinite(args.speed) and 0.01 <= args.speed <= 1000.0):
        raise InputError(f"--speed {args.speed:g}: expected from 0.01 to 1000 times real time")
    if not (math.isfinite(args.start) and args.start >= 0.0):
        raise InputError(f"--start {args.start:g}: expected a time from 0 s")
    if args.replay is not None:
        from cellsim.blackbox import BlackBoxError
        from cellsim.validation.check import CheckError

        try:
            feed = ReplayFeed(args.replay, args.speed, args.start)
        except (CheckError, BlackBoxError) as e:
            raise InputError(str(e)) from None
        _run(Dashboard(feed))
        return EXIT_OK
    from cellsim.cli.common import _network_security, warn_insecure
    from cellsim.live.session import session_config

    security = _network_security(args, args.role)
    config = dict(**security, listen=args.listen, connect=args.connect, config_file=args.config,
                  listen_by_default=False, wait=2.0)
    session_config(**config)  # a bad endpoint or configuration file: one line, exit 2, before the screen opens
    warn_insecure(security)

    def open_session():
        import zenoh

        return zenoh.open(session_config(**config))

    feed = LiveFeed(open_session, args.cell, may_switch=args.role == "engineer")  # waits for a twin to be reachable, saying so
    try:
        _run(Dashboard(feed))
    finally:
        feed.close()
    return EXIT_OK


def _run(app) -> None:
    """Run the dashboard ``app``; ended by SIGTERM, the command ends as interrupted (exit 130), as Ctrl-C ends it. A
    SIGTERM before the screen is up is noted (raising then would land inside Textual starting, which lost it) and
    ends the app once it is mounted; from then on the app's loop takes SIGTERM itself."""
    import signal

    def noted(*_):
        app.terminated = True

    before = signal.signal(signal.SIGTERM, noted)
    try:
        app.run()
    finally:
        signal.signal(signal.SIGTERM, before)
    if app.terminated:
        raise KeyboardInterrupt
