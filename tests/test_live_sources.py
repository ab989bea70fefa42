"""Network messages into a live twin's entity: the sample source takes samples and failure messages in order."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from pydrake.systems.analysis import Simulator

from cellsim.channels import BOOL
from cellsim.live.codec import encode_failure, encode_fields
from cellsim.live.sources import LiveClock, ZenohSampleSource


def _source():
    spec = SimpleNamespace(signal="broken", type=BOOL)
    entity = SimpleNamespace(module="light_barrier", sample_fields=("broken",), channels=[(spec, None)], period=0.04)
    source = ZenohSampleSource(entity, LiveClock(wall_at_zero=1000.0), time_step=0.002)
    simulator = Simulator(source)
    simulator.Initialize()
    return source, simulator


def _sample(source, simulator, t: float) -> np.ndarray:
    simulator.AdvanceTo(t)
    return source.get_output_port().Eval(simulator.get_context())


def test_a_failure_message_makes_the_link_stale_or_corrupt_at_once_and_a_sample_restores_it():
    source, simulator = _source()
    source.deliver(encode_fields(1000.01, 1, {"broken": False}))
    assert np.allclose(_sample(source, simulator, 0.05), [0.01, 1.0, 0.0])
    source.deliver(encode_failure(1000.06, 2, "corrupt"))
    t, valid, broken = _sample(source, simulator, 0.09)
    assert math.isclose(t, 0.06) and valid == 1.0 and math.isnan(broken)  # fresh but unusable: corrupt
    source.deliver(encode_failure(1000.10, 3, "stale"))
    t, valid, _ = _sample(source, simulator, 0.13)
    assert valid == 0.0  # the entity reads its link stale
    source.deliver(encode_failure(1000.05, 4, "corrupt"))  # older than the last taken: dropped
    source.deliver(encode_fields(1000.14, 5, {"broken": True}))
    assert np.allclose(_sample(source, simulator, 0.17), [0.14, 1.0, 1.0])
    assert source.rejected == 1
