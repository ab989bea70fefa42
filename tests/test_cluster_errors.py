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

        def slots(self):
            return 2

        def close(self):
            pass

    monkeypatch.setattr("cellsim.campaign.cluster.ClusterPool", FailingCluster)
    with pytest.raises(engine.CampaignError, match="has cellsim 0.0, the campaign 0.1; .*run the same command again"):
        with engine.worker_pool(2, "tcp://127.0.0.1:1", tmp_path) as workers:
            engine.run_all(workers, None, tmp_path, [(0, None, None)], {}, lambda result: None)


def test_a_run_handed_to_the_cluster_is_never_cancelled_and_is_kept_when_it_finishes(tmp_path):
    """A campaign stopping early (--until-bound, a search's end) cancels the runs it has not started; a run handed to
    a cluster has started (the campaign hands it no more than its threads), so, as on a local pool, it cannot be
    cancelled and its result is kept (an audit found the cluster's runs cancelled while running on a worker and
    dropped, a cluster campaign undercounting what a local one counts)."""
    import threading

    from cellsim.campaign.cluster import ClusterPool

    class Task:  # what Client.submit returns, as much of it as the pool uses
        key = "cellsim-run-3"

        def __init__(self):
            self.callbacks, self.cancelled = [], False

        def add_done_callback(self, callback):
            self.callbacks.append(callback)

        def cancel(self):
            self.cancelled = True

        def result(self):  # the worker's run: its result and the files to write (none here)
            return {"index": 3, "out": "runs/0003"}, {}

    class Client:
        def submit(self, *args, **kwargs):
            self.task = Task()
            return self.task

        def nthreads(self):
            return {"tcp://127.0.0.1:1": 2, "tcp://127.0.0.1:2": 1}

    pool = object.__new__(ClusterPool)  # no scheduler: only submit's futures are under test
    pool.client, pool._tasks, pool._lock = Client(), [], threading.Lock()
    pool.inputs_dir, pool.digest, pool.snapshot, pool.version, pool.result_name = "", "", None, "", "result.json"
    assert pool.slots() == 3
    future = pool.submit(lambda: None, None, tmp_path, 3)
    assert future.running() and not future.cancel() and not pool.client.task.cancelled
    for callback in pool.client.task.callbacks:  # the task ends on the worker
        callback(pool.client.task)
    assert future.result(timeout=0) == {"index": 3, "out": "runs/0003"}
