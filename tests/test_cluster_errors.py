"""A run that fails on the cluster itself (a worker of another cellsim, a run lost on too many workers)
ends the campaign with one CampaignError line, not a traceback (no cluster needed: the pool is faked)."""

from __future__ import annotations

import concurrent.futures

import pytest

import cellsim.campaign.engine as engine
from cellsim.campaign.cluster import ClusterError


def test_a_failure_on_the_cluster_is_one_campaign_error_that_says_how_to_resume(monkeypatch, tmp_path):
    class FailingCluster:
        address = "tcp://127.0.0.1:1"

        def __init__(self, *args):
            pass

        def submit(self, *args):
            future = concurrent.futures.Future()
            future.set_exception(ClusterError("worker tcp://127.0.0.1:2 has cellsim 0.0, the campaign 0.1"))
            return future

        def close(self):
            pass

    monkeypatch.setattr("cellsim.campaign.cluster.ClusterPool", FailingCluster)
    with pytest.raises(engine.CampaignError, match="has cellsim 0.0, the campaign 0.1; .*run the same command again"):
        with engine.worker_pool(2, "tcp://127.0.0.1:1", tmp_path) as workers:
            engine.run_all(workers, None, tmp_path, [(0, None, None)], {}, lambda result: None)


def test_a_run_cancelled_on_the_cluster_counts_as_done_for_whoever_waits_on_it():
    """A search that stops with a run in flight cancels it and waits for the rest: the cancelled run's future must
    count as done (no executor stands behind it to say so), or the search waits for ever. Its task is cancelled too."""
    import threading
    from concurrent.futures import FIRST_COMPLETED, wait
    from pathlib import Path

    from cellsim.campaign.cluster import ClusterPool

    class Task:  # what Client.submit returns, as much of it as the pool uses
        key = "cellsim-run-3"

        def __init__(self):
            self.callbacks, self.cancelled = [], False

        def add_done_callback(self, callback):
            self.callbacks.append(callback)

        def cancel(self):
            self.cancelled = True

    class Client:
        def submit(self, *args, **kwargs):
            self.task = Task()
            return self.task

    pool = object.__new__(ClusterPool)  # no scheduler: only submit's futures are under test
    pool.client, pool._tasks, pool._lock = Client(), [], threading.Lock()
    pool.inputs_dir, pool.digest, pool.snapshot, pool.version, pool.result_name = "", "", None, "", "result.json"
    future = pool.submit(lambda: None, None, Path("."), 3)
    threading.Timer(0.05, future.cancel).start()
    done, _ = wait([future], timeout=30, return_when=FIRST_COMPLETED)
    assert future in done and future.cancelled() and pool.client.task.cancelled
