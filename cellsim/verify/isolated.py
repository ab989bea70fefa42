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

import contextlib
import gc
import os
import pickle
import signal
import time


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
    return _side_by_side([work], 1, say)[0]


def side_by_side(works: list, at_once: int | None = None) -> list:
    """Each ``work(say)`` of ``works`` in a forked child of its own, at most ``at_once`` at a time (default: the
    cores this process may use); their results in order. The children are collected in the order of ``works``: the
    first error found so is raised as soon as its child has ended, the children still at work stopped (as an
    interrupt stops them) and the work not yet started never started, so a batch that has failed is not waited out
    beyond the children before the failing one."""
    if not hasattr(os, "fork") or len(works) < 2:
        return [work(lambda text: None) for work in works]
    return _side_by_side(works, at_once or cores())


def _side_by_side(works: list, at_once: int, say=None) -> list:
    """The work of :func:`side_by_side` (``say``: the first child's stages, for a batch of one). Interrupted (Ctrl-C,
    SIGTERM), every child not yet reaped is stopped and reaped before the interrupt goes on: a PID is signalled only
    while its child is unreaped (never one the system may have given to another process), and the moments when a
    child is forked or reaped, or the children are killed, hold the two signals off until they are done."""
    outcomes = []
    for first in range(0, len(works), at_once):
        waiting: list[tuple[int, int]] = []  # the children whose pipes are not read yet
        unreaped: list[int] = []
        try:
            with _signals_held():  # each child forked and known before an interrupt can come
                for work in works[first:first + at_once]:
                    waiting.append(_start(work))
                    unreaped.append(waiting[-1][0])
            while waiting:
                outcomes.append(_collect(waiting.pop(0), say if not outcomes else None, unreaped))
                if outcomes[-1][0] != "result":
                    _result(outcomes[-1])  # raised now: the children still at work are stopped below, not waited for
        except BaseException:
            with _signals_held():  # the clean-up runs to its end (its wait alone can be cut short)
                for _, readable in waiting:
                    os.close(readable)
                _stop(unreaped)  # the child interrupted and the others not reaped yet, at once
            raise
    return [_result(outcome) for outcome in outcomes]


def cores() -> int:
    """The cores this process may run on."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def _start(work) -> tuple[int, int]:
    """Fork a child running ``work``: (its pid, the pipe its stages and result come through). Called with SIGINT and
    SIGTERM held (:func:`_signals_held`): the child acts on them only once inside the ``try`` that ends it by
    ``os._exit``, so it never runs its parent's code (a caller's ``except`` or ``finally``, the command's exit)."""
    readable, writable = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: report, then leave without running the parent's exit handlers
        status = 1
        try:
            os.close(readable)
            # stopped (:func:`_stop`), or Ctrl-C at the terminal (the whole group hears it, then the parent stops
            # it): taken once, as Ctrl-C; a second signal must not cut short the clean-up the first starts
            signal.signal(signal.SIGTERM, _interrupt_once)
            signal.signal(signal.SIGINT, _interrupt_once)
            if _HEARD:  # one came between the fork and these handlers: acted on now, inside the try
                _interrupt_once(_HEARD[0], None)
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
            status = 0
        except BaseException:  # noqa: BLE001 - the pipe is gone (the parent was interrupted)
            status = 1
        finally:
            try:
                gc.collect()  # what a cut-short work left in reference cycles (a black box's connection) is closed now
            finally:
                os._exit(status)
    os.close(writable)
    return pid, readable


def _collect(child: tuple[int, int], say, unreaped: list[int]) -> tuple[str, object]:
    """The child's stages (to ``say``) and its outcome once it has ended and is reaped (its pid then taken out of
    ``unreaped``, with the signals held), for :func:`_result`: ("result", value), ("error", exception) or ("stopped",
    how). An interrupt while it runs or ends propagates with the child unreaped (the caller stops it)."""
    pid, readable = child
    say = say or (lambda text: None)
    outcome = None
    with os.fdopen(readable, "rb") as pipe:
        while True:
            try:
                kind, value = pickle.load(pipe)
            except EOFError:
                break
            except Exception as e:  # noqa: BLE001 - a message that does not unpickle (an exception whose arguments
                # differ from its __init__'s): said in words, the rest of the stream (unreadable now) read to its end
                # so that the child can end, and the others still collected
                outcome = ("error", RuntimeError(f"a child's message could not be read: {type(e).__name__}: {e}"))
                pipe.read()
                break
            if kind == "stage":
                say(value)
            else:
                outcome = (kind, value)
    while _ends_within(pid, 1.0) is False:  # (its pipe closed, it ends: waited for interruptibly, not reaped)
        pass
    with _signals_held():
        _, status = os.waitpid(pid, 0)
        unreaped.remove(pid)
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
    """End the children ``pids`` (none of them reaped yet) and reap them, called with SIGINT and SIGTERM held
    (:func:`_signals_held`): each asked at once (SIGTERM, which a child takes as Ctrl-C: a simulation records its run
    as interrupted and closes its black box, as a run stopped at the command line does), then waited for together
    until ``grace`` seconds have passed, and killed if still there (Storm deep in a build hears no signal until it
    returns to Python). Another interrupt cuts the wait short, never the asking, killing or reaping."""
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    waiting = list(pids)
    while waiting and not _HEARD and time.monotonic() < deadline:  # another interrupt cuts the wait short
        if _ends_within(waiting[0], min(0.1, max(0.0, deadline - time.monotonic()))) is not False:
            waiting.pop(0)  # ended (or no pidfd to wait on: killed below at once)
    for pid in list(pids):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)  # (one that has ended is a zombie until reaped: no error)
        os.waitpid(pid, 0)
        pids.remove(pid)


_STOPPING = (signal.SIGINT, signal.SIGTERM)
_HEARD: list[int] = []
"""The signals heard while they are held (:func:`_signals_held`), in order."""


@contextlib.contextmanager
def _signals_held():
    """SIGINT and SIGTERM held off in the block: heard (in ``_HEARD``), not acted on; once it ends, the handlers in
    force before are put back and the first one heard is raised again for them. Handlers, not the signal mask: Python
    runs its handlers in the main thread whichever thread the system gives a signal to. Only the main thread has
    handlers: elsewhere the block holds nothing."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    del _HEARD[:]
    before = {sig: signal.signal(sig, _hear) for sig in _STOPPING}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
        heard = list(_HEARD)
        del _HEARD[:]
        if heard:
            signal.raise_signal(heard[0])


def _hear(signum, frame):
    _HEARD.append(signum)


def _ends_within(pid: int, seconds: float) -> bool | None:
    """Whether child ``pid`` ends within ``seconds``, waited for as an event (its pidfd turning readable; an ended
    child stays unreaped); None where there is no pidfd (an old kernel): not waited for."""
    import select

    try:
        handle = os.pidfd_open(pid)
    except (AttributeError, OSError):
        return None
    try:
        readable, _, _ = select.select([handle], [], [], seconds)
        return bool(readable)
    finally:
        os.close(handle)
