"""The command line's side of Meshcat: open it on loopback, wait for a browser, serve until closed.

Meshcat listens on localhost only, on the first free port from 7000. How it
ends: on a terminal, Enter closes it (exit 0) and Ctrl-C interrupts (exit 130);
without a terminal (a script, a test) it serves until SIGINT or SIGTERM (exit 130).
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path


WAIT_DEFAULT = 60.0
"""Seconds ``simulate --meshcat`` waits for a browser on a terminal before simulating anyway (none without one)."""


def open_meshcat():
    """A Meshcat server on localhost (never another interface)."""
    from pydrake.geometry import Meshcat, MeshcatParams

    return Meshcat(MeshcatParams(host="localhost"))


def serve_until_closed(meshcat, say) -> None:
    """Keep Meshcat serving: until Enter on a terminal, else until interrupted.

    SIGINT arrives as KeyboardInterrupt; the caller makes SIGTERM do the same, from
    before it prints the URL (``cellsim.cli``), so no SIGTERM finds it unprepared.
    """
    if sys.stdin is not None and sys.stdin.isatty():
        try:
            input("Press Enter to close Meshcat (Ctrl-C also ends it). ")
        except EOFError:
            pass
        return
    say("serving Meshcat until interrupted (Ctrl-C, or SIGTERM)")
    forever = threading.Event()
    while not forever.wait(0.5):  # the signal handlers run between these waits
        pass


def cmd_replay(args, input_error) -> int:
    """``cellsim replay RUN --meshcat [--at T] [--speed X]``: play a black box in the browser."""
    from cellsim.visual.replay import ReplayError, check_replay, replay

    if not args.meshcat:
        raise input_error("replay needs --meshcat (the only player so far; the terminal one is `cellsim dashboard --replay`)")
    run = Path(args.run)
    if not run.exists():
        raise input_error(f"{run}: no such run folder or black box")
    try:
        check_replay(run, at=args.at, speed=args.speed)  # every argument checked before Meshcat starts
    except ReplayError as e:
        raise input_error(str(e)) from None
    meshcat = open_meshcat()
    try:
        try:
            played = replay(run, meshcat, at=args.at, speed=args.speed)
        except ReplayError as e:
            raise input_error(str(e)) from None
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
        print(
            f"playing {run} from t = {played.at:g} s to {played.end:g} s at {played.speed:g}x "
            f"({played.frames} frames); the animation's time 0 is t = {played.at:g} s",
            flush=True,
        )
        serve_until_closed(meshcat, lambda line: print(line, flush=True))
    finally:
        del meshcat
    return 0
