"""The recorder (cellsim.services.recorder) on scripted publishers: which messages a black box gets, with
which times and values, read back with sqlite3. The rules (the module's docstring): every channel is looked
at at every update of its publisher, never less often; a value is stamped with the simulated time of the
update that published it; ``on_change`` writes it when it differs from the last written, ``every_sample`` at
every update; the initial state, replaced at t = 0 by the first update, is not written; a run that stops
between two updates keeps what was published last."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from cellsim.channels import ChannelSpec, number_type
from cellsim.services.blackbox import BlackBoxWriter
from cellsim.services.recorder import Recorder


class Script(LeafSystem):
    """Publishes ``values[k]`` at its update at t = k * period (the last value from then on); its initial
    state, before the first update, is ``initial``."""

    def __init__(self, period: float, values: list[float], initial: float = -99.0):
        super().__init__()
        self.period, self.values = period, values
        state = self.DeclareDiscreteState(np.array([initial]))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("y", state)

    def _update(self, context, xd):
        k = round(context.get_time() / self.period)
        xd.get_mutable_vector(0).SetAtIndex(0, self.values[min(k, len(self.values) - 1)])


def record(tmp_path, channels: list[tuple[str, float, str, list[float]]], duration: float,
           drains: list[float] = ()) -> dict[str, list[tuple[float, float]]]:
    """Simulate scripted publishers ``(name, period, record, values)`` for ``duration``,
    draining at ``drains`` and at the end; every channel's messages ``[(t, value)]`` read back with sqlite3."""
    builder = DiagramBuilder()
    taps = []
    for name, period, policy, values in channels:
        script = builder.AddNamedSystem(name, Script(period, values))
        spec = ChannelSpec(name, "y", number_type(None), period, policy)
        taps.append((spec, script.get_output_port()))
    recorder = Recorder(builder, "blackbox", taps)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    path = tmp_path / "bb.sqlite"
    writer = BlackBoxWriter(path)
    recorder.attach(writer)
    simulator.Initialize()
    context = simulator.get_context()
    for t in [*drains, duration]:
        simulator.AdvanceTo(t)
        recorder.drain(context, final=t == duration)
    writer.close("completed")
    with sqlite3.connect(path) as db:
        rows = db.execute("SELECT t, channel, payload FROM messages ORDER BY rowid").fetchall()
    out: dict[str, list] = {f"{name}.y": [] for name, *_ in channels}
    for t, channel, payload in rows:
        out[channel].append((t, json.loads(payload)["value"]))
    return out


def test_on_change_writes_each_new_value_at_the_time_it_was_published(tmp_path):
    got = record(tmp_path, [("a", 0.1, "on_change", [1, 1, 2, 2, 2, 3, 1])], duration=1.0, drains=[0.35])
    assert got["a.y"] == [(0.0, 1), (0.2, 2), (0.5, 3), (0.6, 1)]


def test_every_sample_writes_every_update(tmp_path):
    got = record(tmp_path, [("c", 0.1, "every_sample", [5, 5, 6])], duration=1.0, drains=[0.45])
    assert [t for t, _ in got["c.y"]] == pytest.approx([0.1 * k for k in range(10)])
    assert [v for _, v in got["c.y"]] == [5, 5] + [6] * 8


def test_the_initial_state_is_never_written_when_the_first_update_replaces_it(tmp_path):
    got = record(tmp_path, [("d", 0.1, "on_change", [7, 8]), ("d2", 0.1, "every_sample", [7, 8])], duration=0.5)
    assert got["d.y"] == [(0.0, 7), (0.1, 8)]
    assert got["d2.y"][0] == (0.0, 7) and -99 not in [v for _, v in got["d2.y"]]


def test_a_run_shorter_than_one_period_keeps_what_its_first_update_published(tmp_path):
    got = record(tmp_path, [("e", 0.5, "on_change", [4, 5])], duration=0.2)
    assert got["e.y"] == [(0.0, 4)]


def test_a_run_stopped_between_two_updates_keeps_the_last_value_published(tmp_path):
    """The update at 0.7 published 70; the run stops at 0.75, before the next look: 70 is kept, at 0.7."""
    got = record(tmp_path, [("f", 0.1, "on_change", [float(10 * k) for k in range(20)]),
                            ("f2", 0.02, "on_change", [0.0] * 100)], duration=0.75)
    assert got["f.y"] == [(pytest.approx(0.1 * k), 10.0 * k) for k in range(8)]


def test_channels_whose_periods_are_no_multiple_of_the_shortest_keep_their_own_updates(tmp_path):
    """0.02 s, 0.05 s and 0.1 s in one log: looked at on ticks of their common divisor (0.01 s), each at its
    own updates (a 0.05 s channel on 0.02 s ticks was looked at every 0.04 s, and its values mis-stamped)."""
    got = record(tmp_path, [("g", 0.02, "on_change", [0] * 10 + [1] * 100),
                            ("h", 0.05, "every_sample", [float(k) for k in range(100)]),
                            ("i", 0.1, "on_change", [2, 2, 3])], duration=0.4, drains=[0.1, 0.13])
    assert got["g.y"] == [(0.0, 0), (0.2, 1)]
    assert got["h.y"] == [(pytest.approx(0.05 * k), float(k)) for k in range(8)]
    assert got["i.y"] == [(0.0, 2), (0.2, 3)]


def test_the_logs_tick_is_the_greatest_common_divisor_of_the_periods():
    from cellsim.services.recorder import base_period

    assert base_period([0.02, 0.05, 0.1]) == pytest.approx(0.01)
    assert base_period([0.04, 0.1]) == pytest.approx(0.02)
    assert base_period([0.002, 0.04, 0.1]) == pytest.approx(0.002)
    assert base_period([0.5]) == pytest.approx(0.5)
