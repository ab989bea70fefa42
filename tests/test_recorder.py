"""The recorder (cellsim.recorder) on scripted publishers: which messages a black box gets, with
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
from cellsim.blackbox import BlackBoxWriter
from cellsim.recorder import Recorder


class Script(LeafSystem):
    """Publishes ``values[k]`` at its update at t = k * period (the last value from then on); its initial
    state, before the first update, is ``initial``."""

    def __init__(self, period: float, values: list, initial: float = -99.0, size: int = 1):
        super().__init__()
        self.period, self.values = period, values
        state = self.DeclareDiscreteState(np.full(size, initial))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("y", state)

    def _update(self, context, xd):
        k = round(context.get_time() / self.period)
        xd.get_mutable_vector(0).SetFromVector(np.atleast_1d(np.asarray(self.values[min(k, len(self.values) - 1)], float)))


def record(tmp_path, channels: list[tuple], duration: float,
           drains: list[float] = ()) -> dict[str, list[tuple[float, float]]]:
    """Simulate scripted publishers ``(name, period, record, values[, type])`` for ``duration``,
    draining at ``drains`` and at the end; every channel's messages ``[(t, value)]`` read back with sqlite3
    (in the order they were written)."""
    builder = DiagramBuilder()
    taps = []
    for name, period, policy, values, *kind in channels:
        ctype = kind[0] if kind else number_type(None)
        script = builder.AddNamedSystem(name, Script(period, values, size=ctype.size))
        spec = ChannelSpec(name, "y", ctype, period, policy)
        taps.append((spec, script.get_output_port()))
    recorder = Recorder(builder, "blackbox", taps)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "bb.sqlite"
    writer = BlackBoxWriter(path)
    recorder.attach(writer)
    simulator.Initialize()
    context = simulator.get_context()
    for t in drains:
        simulator.AdvanceTo(t)
        recorder.drain(context)
    simulator.AdvanceTo(duration)
    recorder.drain(context, final=True)
    writer.close("completed")
    db = sqlite3.connect(path)
    rows = db.execute("SELECT t, channel, source, payload FROM messages ORDER BY rowid").fetchall()
    db.close()
    out: dict[str, list] = {f"{name}.y": [] for name, *_ in channels}
    for t, channel, source, payload in rows:
        assert source == channel.split(".")[0]
        out[channel].append((t, json.loads(payload)["value"]))
    out["order"] = [channel for _, channel, _, _ in rows]
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
    from cellsim.recorder import base_period

    assert base_period([0.02, 0.05, 0.1]) == pytest.approx(0.01)
    assert base_period([0.04, 0.1]) == pytest.approx(0.02)
    assert base_period([0.002, 0.04, 0.1]) == pytest.approx(0.002)
    assert base_period([0.5]) == pytest.approx(0.5)


def test_enumerations_booleans_and_vectors_are_written_as_their_values_each_on_its_own_changes(tmp_path):
    from cellsim.channels import BOOL, enum_type, vector_type
    from cellsim.vocabulary import Range

    got = record(tmp_path, [
        ("e", 0.1, "on_change", [0, 0, 2, 1, 1], enum_type(Range)),
        ("b", 0.1, "on_change", [1, 0, 0, 1], BOOL),
        # a vector whose second component alone changes: a change of the channel
        ("v", 0.1, "on_change", [[1.0, 2.0], [1.0, 2.0], [1.0, 3.5], [1.0, 3.5]], vector_type(2, "m")),
        ("w", 0.1, "on_change", [[0.5, 0.5], [0.25, 0.5], [0.25, 0.5], [0.25, 0.5]], vector_type(2, "m")),
    ], duration=0.45, drains=[0.15])
    assert got["e.y"] == [(0.0, "far"), (0.2, "close"), (0.3, "near")]
    assert got["b.y"] == [(0.0, True), (0.1, False), (0.3, True)]
    assert got["v.y"] == [(0.0, [1.0, 2.0]), (0.2, [1.0, 3.5])]
    assert got["w.y"] == [(0.0, [0.5, 0.5]), (0.1, [0.25, 0.5])]


def test_the_messages_of_one_look_are_written_by_period_then_as_declared(tmp_path):
    """A look at the log writes its channels by period, then in the order declared; what the final drain adds
    comes last (each channel's messages are in time order; the black box's index orders the rest)."""
    got = record(tmp_path, [("slow", 0.2, "every_sample", [1.0]), ("zeta", 0.1, "every_sample", [2.0]),
                            ("alpha", 0.1, "every_sample", [3.0])], duration=0.25)
    assert got["order"] == ["zeta.y", "alpha.y", "zeta.y", "alpha.y", "slow.y", "zeta.y", "alpha.y", "slow.y"]
    assert got["slow.y"] == [(0.0, 1.0), (0.2, 1.0)] and got["zeta.y"] == [(0.0, 2.0), (0.1, 2.0), (0.2, 2.0)]


def test_a_drain_without_a_black_box_writes_nothing_and_says_so():
    builder = DiagramBuilder()
    script = builder.AddNamedSystem("s", Script(0.1, [1.0, 2.0]))
    recorder = Recorder(builder, "blackbox", [(ChannelSpec("s", "y", number_type(None), 0.1), script.get_output_port())])
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    simulator.AdvanceTo(0.35)
    assert recorder.drain(simulator.get_context()) == 0 and recorder.name == "blackbox" and recorder.writer is None


def test_a_cells_black_box_has_every_channel_from_its_first_instant(tmp_path):
    """The recorder built by the cell (its blackbox module): every channel of the welding cell has its message at
    t = 0, and the values are the cell's (the robot starts exchanging the workpiece, in normal mode)."""
    from conftest import run, welding_cell

    bb = run(welding_cell(), tmp_path / "run", duration=0.3, seed=1)
    channels = bb.channels()
    first = {}
    for m in bb.messages():
        first.setdefault(m.channel, (m.t, m.value))
    assert set(first) == set(channels) and all(t == 0.0 for t, _ in first.values())
    assert first["robot.safety_mode"] == (0.0, "normal") and first["robot.activity"] == (0.0, "exchWrkp")


def _holds(tmp_path, channels, duration, formula) -> tuple[bool, float | None]:
    """Record scripted publishers, read the black box back as a trace and judge ``formula`` on it."""
    from cellsim.blackbox import BlackBox
    from cellsim.logic.mtl import TraceEvaluator
    from cellsim.logic.syntax import parse
    from cellsim.validation.traces import trace_of_run

    record(tmp_path, channels, duration)
    with BlackBox(tmp_path / "bb.sqlite") as bb:
        run = trace_of_run(bb)
    evaluation = TraceEvaluator(run.trace).evaluate(parse(formula, run.vocabulary))
    return evaluation.holds, evaluation.violated_at


# A scanner updating every 0.04 s reads a person at 0.5 m for one update at t = 1.04 s (an excursion of 0.04 s,
# shorter than 0.1 s, between two tenths); a controller updating every 0.02 s reads it at 1.06 s and slows the arm.
SCAN = ("scan", 0.04, "on_change", [5.0] * 26 + [0.5] + [5.0] * 30)
CONTROL = ("ctl", 0.02, "on_change", [0.0] * 53 + [1.0] * 3 + [0.0] * 40)


def test_a_violation_shorter_than_a_tenth_of_a_second_is_caught(tmp_path):
    holds, at = _holds(tmp_path, [SCAN, CONTROL], 2.0, "G(scan.y >= 1)")
    assert not holds and at == pytest.approx(1.04)


def test_a_reaction_in_time_is_judged_on_the_values_the_controller_acted_on(tmp_path):
    """The controller reacted one of its periods after the scanner's reading: ``F[0, 0.03s]`` holds. Recorded
    only every 0.1 s (as the robot's telemetry once was), the reaction would have read 0.06 s late."""
    holds, _ = _holds(tmp_path, [SCAN, CONTROL], 2.0, "G(scan.y < 1 -> F[0, 0.03s] ctl.y == 1)")
    assert holds
    got = record(tmp_path / "again", [SCAN, CONTROL], 2.0)
    assert got["ctl.y"][:2] == [(0.0, 0.0), (1.06, 1.0)] and got["scan.y"][1] == (1.04, 0.5)


def test_the_robots_speed_and_joints_are_recorded_at_every_update_of_its_controller(tmp_path):
    """While the arm moves its measured speed and joints change at each 20 ms update, and each is in the black box."""
    from conftest import welding_cell
    from cellsim.simulation import simulate

    simulate(welding_cell(), tmp_path / "run", duration=3.0)
    db = sqlite3.connect(tmp_path / "run" / "blackbox.sqlite")
    for channel in ("robot.tool_speed", "robot.joint_positions"):
        times = np.array([t for (t,) in db.execute("SELECT t FROM messages WHERE channel = ? ORDER BY t", (channel,))])
        steps = np.round(np.diff(times), 9)
        assert len(times) > 50 and np.allclose(steps / 0.02, np.round(steps / 0.02)) and np.median(steps) == pytest.approx(0.02)
    db.close()
