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
