"""Work in processes of their own: Storm, so that Storm stopping cannot stop ``verify``; the twin's replays of
a witness, side by side on the machine's cores.

Sylvan, the decision-diagram library Storm builds with, takes its tables at start
and, when a model outgrows them, prints "BDD Unique table full" and ends the whole
process with exit status 1: the status ``cellsim verify`` gives a confirmed safety
finding. So the model is built and checked in a forked child: the parent hears
each stage as the child reaches it (the caller's ``say``), gets the result back
(pickled through a pipe), and learns from the child's exit when it stopped without
one (:class:`ProcessStopped`), which the caller can answer (build again with larger
tables) or report. A fork shares the parent's loaded libraries and the abstract
model as it is, so it costs milliseconds; the child's memory, Sylvan's tables
included, goes back to the system when it ends.

Where ``os.fork`` does not exist the work runs in this process, as before. A fork
copies only the calling thread, so a lock another thread of the caller held at that
moment (a notebook's, a server's: Python's logging, which Drake's messages go
through) stays held in the child; ``cellsim verify`` has no other threads, and Sylvan
is started in children only, never in the process that forks.

:func:`side_by_side` runs several pieces of work at once, each in a child of its
own (a witness's later starts on the twin: each a whole simulation), and gives
their results in order.
"""

from __future__ import annotations

import os
import pickle
import signal


class ProcessStopped(Exception):
    """The child ended without a result: its exit status or the signal that ended it."""

    def __init__(self, how: str):
        super().__init__(how)
        self.how = how


def in_own_process(work, say=None):
    """``work(say)`` in a forked child; returns what it returns, raises what it raises (pickled), and raises
    :class:`ProcessStopped` when the child ends without either. ``say(text)``: each stage, in this process."""
    say = say or (lambda text: None)
    if not hasattr(os, "fork"):
        return work(say)
    return _result(_collect(_start(work), say))


def side_by_side(works: list, at_once: int | None = None) -> list:
    """Each ``work(say)`` of ``works`` in a forked child of its own, at most ``at_once`` at a time (default: the
    cores this process may use); their results in order (the first error raised, once every child has ended)."""
    if not hasattr(os, "fork") or len(works) < 2:
        return [work(lambda text: None) for work in works]
    at_once = at_once or cores()
    outcomes = []
    for first in range(0, len(works), at_once):
        started = [_start(work) for work in works[first:first + at_once]]
        for i, child in enumerate(started):
            try:
                outcomes.append(_collect(child, None, others=[pid for pid, _ in started[i + 1:]]))
            except BaseException:  # interrupted: _collect has stopped this batch's others too
                for _, readable in started[i + 1:]:
                    os.close(readable)
                raise
    return [_result(outcome) for outcome in outcomes]


def cores() -> int:
    """The cores this process may run on."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def _start(work) -> tuple[int, int]:
    """Fork a child running ``work``: (its pid, the pipe its stages and result come through)."""
    readable, writable = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: report, then leave without running the parent's exit handlers
        os.close(readable)
        # stopped (:func:`_stop`), or Ctrl-C at the terminal (the whole group hears it, then the parent stops it):
        # taken once, as Ctrl-C; a second signal must not cut short the clean-up it starts (a black box closing)
        signal.signal(signal.SIGTERM, _interrupt_once)
        signal.signal(signal.SIGINT, _interrupt_once)
        status = 0
        try:
            with os.fdopen(writable, "wb") as pipe:
                def tell(text: str) -> None:
                    pickle.dump(("stage", text), pipe)
                    pipe.flush()

                try:
                    message = ("result", work(tell))
                except BaseException as e:  # noqa: BLE001 - carried to the parent, which raises it
                    # without its frames, which go now: what they held open (a black box half opened) is closed
                    # before the child leaves by os._exit, which runs no clean-up
                    message = ("error", e.with_traceback(None))
                try:
                    pickle.dump(message, pipe)
                except Exception as e:  # noqa: BLE001 - an exception that does not pickle: said in words
                    pickle.dump(("error", RuntimeError(f"{type(e).__name__}: {e}")), pipe)
        except BaseException:  # noqa: BLE001 - the pipe is gone (the parent was interrupted)
            status = 1
        finally:
            import gc

            try:
                gc.collect()  # what a cut-short work left in reference cycles (a black box's connection) is closed now
            finally:
                os._exit(status)
    os.close(writable)
    return pid, readable


def _collect(child: tuple[int, int], say, others: list[int] = ()) -> tuple[str, object]:
    """The child's stages (to ``say``) and its outcome once it has ended and is reaped, for :func:`_result`:
    ("result", value), ("error", exception) or ("stopped", how). Interrupted meanwhile, the child and ``others``
    (children started beside it, not collected yet) are stopped and reaped."""
    pid, readable = child
    say = say or (lambda text: None)
    outcome = None
    try:
        with os.fdopen(readable, "rb") as pipe:
            while True:
                try:
                    kind, value = pickle.load(pipe)
                except EOFError:
                    break
                if kind == "stage":
                    say(value)
                else:
                    outcome = (kind, value)
    except BaseException:
        _stop([pid, *others])  # interrupted: the child goes with us, and the others not collected yet, at once
        raise
    _, status = os.waitpid(pid, 0)
    if outcome is None:
        return "stopped", (f"signal {signal.Signals(os.WTERMSIG(status)).name}" if os.WIFSIGNALED(status)
                           else f"exit status {os.WEXITSTATUS(status)}")
    return outcome


def _result(outcome: tuple[str, object]):
    """What a child's outcome (:func:`_collect`) gives: its value, or its error raised (ProcessStopped for a child
    that ended without either)."""
    kind, value = outcome
    if kind == "stopped":
        raise ProcessStopped(value)
    if kind == "error":
        raise value
    return value


STOP_GRACE = 5.0
"""Seconds a child asked to stop has to end on its own (a twin's run closing its black box) before it is killed."""


def _interrupt_once(signum, frame):
    """A child's first SIGTERM or SIGINT: KeyboardInterrupt, and no more of either (the clean-up it starts runs to its
    end; the parent kills a child that takes longer than STOP_GRACE)."""
    # (a Python handler that does nothing, not SIG_IGN: one already on its way would then raise OSError, "ignored
    # due to race condition", in the middle of the clean-up)
    signal.signal(signal.SIGTERM, _ignore)
    signal.signal(signal.SIGINT, _ignore)
    raise KeyboardInterrupt


def _ignore(signum, frame):
    """A child's later SIGTERM or SIGINT: nothing (its first one's clean-up runs on)."""


def _stop(pids: list[int], grace: float = STOP_GRACE) -> None:
    """End the children ``pids`` and reap them: each asked at once (SIGTERM, which a child takes as Ctrl-C: a
    simulation records its run as interrupted and closes its black box, as a run stopped at the command line does),
    then waited for together until ``grace`` seconds have passed, and killed if still there (Storm deep in a build
    hears no signal until it returns to Python). A second interrupt while waiting cuts the wait short, never the
    killing and reaping."""
    import time

    for pid in pids:
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + grace
    try:
        for pid in pids:
            _ends_within(pid, max(0.0, deadline - time.monotonic()))
    finally:
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)  # (one that has ended is a zombie until reaped: no error)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)


def _ends_within(pid: int, seconds: float) -> bool:
    """Whether child ``pid`` ends within ``seconds``: waited for as an event (its pidfd turning readable)."""
    import select

    try:
        handle = os.pidfd_open(pid)
    except (AttributeError, OSError):  # no pidfd here (an old kernel): it is not waited for
        return False
    try:
        readable, _, _ = select.select([handle], [], [], seconds)
        return bool(readable)
    finally:
        os.close(handle)
