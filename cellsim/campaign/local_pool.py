"""The campaign's local workers: fresh interpreters, replaced now and then, ending with the campaign.

Workers are started with "spawn", not forked: nothing of the parent's Drake state
is shared. A pydrake diagram holding Python systems is never freed (about 2.5 MB a
run), so a worker must not live for ever. The standard library's own answer,
``ProcessPoolExecutor(max_tasks_per_child=...)``, deadlocks on Python 3.11 to 3.13
once a worker retires with tasks still queued (CPython gh-115634: the executor
believes an idle worker exists and never starts a replacement; a 2-worker campaign
stopped for good after its 120th run). So the pool recycles whole executors
itself: after ``runs_per_worker`` tasks per worker it hands new tasks to a new
executor and lets the old one finish what it holds and exit. The caller keeps at
most ``jobs`` tasks in flight (:attr:`LocalPool.slots`), so old and new together
never run more than ``jobs`` tasks at once.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor

RUNS_PER_WORKER = 60
"""Tasks a worker runs before it is replaced (bounds the memory pydrake never gives back)."""

PR_SET_PDEATHSIG = 1
"""prctl(2) option: the signal a process gets when its parent ends (Linux)."""
PARENT_POLL = 0.5
"""How often (s) a worker's watcher checks that the campaign process is alive."""


class LocalPool:
    """``submit(fn, *args)`` onto ``jobs`` local worker processes, replaced every ``runs_per_worker`` tasks each."""

    def __init__(self, jobs: int, runs_per_worker: int | None = None):
        runs_per_worker = RUNS_PER_WORKER if runs_per_worker is None else runs_per_worker
        if jobs < 1 or runs_per_worker < 1:
            raise ValueError("a pool needs at least one worker and one task per worker")
        self.jobs = jobs
        self.slots = jobs
        self._per_executor = jobs * runs_per_worker
        self._retiring: list[threading.Thread] = []
        self._executor = self._new_executor()
        self._submitted = 0

    def _new_executor(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=self.jobs,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(os.getpid(),),
        )

    def submit(self, fn, *args, **kwargs) -> Future:
        if self._submitted >= self._per_executor:
            # the old executor runs what it holds, then its workers exit; a thread waits for them
            retiring = threading.Thread(target=self._executor.shutdown, name="cellsim-pool-retire", daemon=True)
            retiring.start()
            self._retiring.append(retiring)
            self._executor = self._new_executor()
            self._submitted = 0
        self._submitted += 1
        with _main_left_alone():  # (a worker is started, if one is, within this call)
            return self._executor.submit(fn, *args, **kwargs)

    def shutdown(self, cancel: bool = False) -> None:
        """Waits until every worker, of every executor, has exited; ``cancel``: the current
        executor drops the tasks it has not started (a retired one holds at most ``slots``)."""
        self._executor.shutdown(wait=True, cancel_futures=cancel)
        for retiring in self._retiring:
            retiring.join()
        self._retiring.clear()


@contextlib.contextmanager
def _main_left_alone():
    """While workers are started: the caller's script is not theirs to run. A spawned worker runs the parent's main
    module again (as ``__mp_main__``) before its task, so a script that calls ``cellsim.run_campaign`` at its top
    level, with no ``if __name__ == "__main__":`` guard, would start the campaign again in every worker (which then
    dies: the folder is taken). The workers run cellsim's own functions only, so the main module's file is hidden
    from them while they start; a module run with ``-m`` (a spec) is left as it is."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if main is None or path is None or getattr(main, "__spec__", None) is not None:
        yield
        return
    del main.__file__
    try:
        yield
    finally:
        main.__file__ = path


def _init_worker(parent: int) -> None:
    """Workers leave Ctrl-C and SIGTERM (sent to the whole process group, as a batch scheduler does) to the
    campaign, which cancels what has not started and lets running runs finish, so an interruption loses no
    finished run; and they end when the campaign process ends, however it ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _end_with_parent(parent)


def _end_with_parent(parent: int) -> None:
    """End this process as soon as ``parent`` (the campaign) ends, SIGKILL included.

    On Linux the kernel kills it (``PR_SET_PDEATHSIG``; the executor creates
    workers from threads that outlive them: the caller's and its manager
    thread). Everywhere, a daemon thread also watches for the process being
    re-parented, the portable sign that the parent is gone; it also covers a
    parent that died before the prctl call.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass  # no usable libc: the watcher below still ends the worker
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL)
        os._exit(1)

    threading.Thread(target=watch, name="cellsim-parent-watch", daemon=True).start()
