"""Storm in a process of its own, so that Storm stopping cannot stop ``verify``.

Sylvan, the decision-diagram library Storm builds with, takes its tables at start
and, when a model outgrows them, prints "BDD Unique table full" and ends the whole
process with exit status 1: the status ``cellsim verify`` gives a confirmed safety
finding. So the model is built and checked in a forked child: the parent hears
each stage as the child reaches it (the caller's ``say``), gets the result back
(pickled through a pipe), and learns from the child's exit when it stopped without
one (:class:`StormStopped`), which the caller can answer (build again with larger
tables) or report. A fork shares the parent's loaded libraries and the abstract
model as it is, so it costs milliseconds; the child's memory, Sylvan's tables
included, goes back to the system when it ends.

Where ``os.fork`` does not exist the work runs in this process, as before.
"""

from __future__ import annotations

import os
import pickle
import signal


class StormStopped(Exception):
    """The child ended without a result: its exit status or the signal that ended it."""

    def __init__(self, how: str):
        super().__init__(how)
        self.how = how


def in_own_process(work, say=None):
    """``work(say)`` in a forked child; returns what it returns, raises what it raises (pickled), and raises
    :class:`StormStopped` when the child ends without either. ``say(text)``: each stage, in this process."""
    say = say or (lambda text: None)
    if not hasattr(os, "fork"):
        return work(say)
    readable, writable = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: report, then leave without running the parent's exit handlers
        os.close(readable)
        status = 0
        try:
            with os.fdopen(writable, "wb") as pipe:
                def tell(text: str) -> None:
                    pickle.dump(("stage", text), pipe)
                    pipe.flush()

                try:
                    message = ("result", work(tell))
                except BaseException as e:  # noqa: BLE001 - carried to the parent, which raises it
                    message = ("error", e)
                try:
                    pickle.dump(message, pipe)
                except Exception as e:  # noqa: BLE001 - an exception that does not pickle: said in words
                    pickle.dump(("error", RuntimeError(f"{type(e).__name__}: {e}")), pipe)
        except BaseException:  # noqa: BLE001 - the pipe is gone (the parent was interrupted)
            status = 1
        finally:
            os._exit(status)
    os.close(writable)
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
        os.kill(pid, signal.SIGKILL)  # interrupted: the child goes with us
        os.waitpid(pid, 0)
        raise
    _, status = os.waitpid(pid, 0)
    if outcome is None:
        how = (f"signal {signal.Signals(os.WTERMSIG(status)).name}" if os.WIFSIGNALED(status)
               else f"exit status {os.WEXITSTATUS(status)}")
        raise StormStopped(how)
    kind, value = outcome
    if kind == "error":
        raise value
    return value
