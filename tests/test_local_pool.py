"""The campaign's local pool replaces its workers every so many runs without ever stalling
(CPython gh-115634: ``max_tasks_per_child`` deadlocks with tasks queued on Python 3.11)."""

from __future__ import annotations

import os

from cellsim.campaign.local_pool import LocalPool


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie the executor has not reaped yet is as good as gone
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ", 1)[1][0] != "Z"
    except OSError:
        return False


def test_workers_are_replaced_and_a_backlog_far_beyond_their_quota_finishes():
    pool = LocalPool(2, runs_per_worker=2)
    try:
        # 20 tasks queued at once: 5 executors' worth, where the standard library's
        # max_tasks_per_child stops for good after the first 4
        futures = [pool.submit(os.getpid) for _ in range(20)]
        pids = [f.result(timeout=120) for f in futures]
    finally:
        pool.shutdown()
    assert len(set(pids)) >= 5  # at least one fresh worker per 4 tasks
    assert os.getpid() not in pids
    assert not any(_alive(pid) for pid in set(pids))  # shutdown waits for every generation's workers


def test_a_cancelled_shutdown_drops_what_has_not_started():
    pool = LocalPool(1, runs_per_worker=100)
    futures = [pool.submit(sum, range(10)) for _ in range(50)]
    pool.shutdown(cancel=True)
    assert all(f.done() for f in futures)
    assert any(f.cancelled() for f in futures)
