"""Network messages into a live twin's entity: the sample source judges them by the one link rule."""

from __future__ import annotations

import contextlib
import json
import time
from types import SimpleNamespace

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from cellsim.channels import BOOL
from cellsim.codec import encode_failure, encode_fields
from cellsim.link import Fault
from cellsim.live.systems import LiveClock, ZenohSampleSource
from cellsim.vocabulary import PhysicalLink

OK, STALE, CORRUPT, RECOVERING = (float(link.code) for link in
                                  (PhysicalLink.OK, PhysicalLink.STALE, PhysicalLink.CORRUPT, PhysicalLink.RECOVERING))


def _source(recover_after: int = 1, stale_after: float = 0.5):
    spec = SimpleNamespace(signal="broken", type=BOOL)
    twin = SimpleNamespace(stale_after=stale_after, recover_after=recover_after)
    entity = SimpleNamespace(module="light_barrier", sample_fields=("broken",), channels=[(spec, None)], period=0.04,
                             twin=twin)
    clock = LiveClock()
    clock.start()
    source = ZenohSampleSource(entity, clock, time_step=0.002)
    simulator = Simulator(source)
    simulator.set_target_realtime_rate(1.0)  # as live: arrivals and the watchdog on one clock
    simulator.Initialize()
    return source, simulator


def _after(source, simulator, t: float) -> np.ndarray:
    """The source's output once it has drained at simulated time ``t``."""
    simulator.AdvanceTo(t)
    return source.get_output_port().Eval(simulator.get_context())


def test_a_failure_message_makes_the_link_stale_or_corrupt_at_once_and_a_sample_restores_it():
    source, simulator = _source()
    now = time.time()
    source.deliver(encode_fields(now, 1, {"broken": False}))
    assert _after(source, simulator, 0.05)[1:].tolist() == [OK, 0.0]
    source.deliver(encode_failure(now, 2, Fault.CRC))  # the bridge forwards the fault its checks found
    assert _after(source, simulator, 0.09)[1] == CORRUPT
    source.deliver(encode_failure(now, 3, Fault.TIMEOUT))
    assert _after(source, simulator, 0.13)[1] == STALE
    assert source.rejected == 0  # a forwarded failure is the link's, not a message refused
    source.deliver(encode_fields(now, 4, {"broken": True}))
    assert _after(source, simulator, 0.17)[1:].tolist() == [OK, 1.0]


def test_a_repeated_message_is_refused_a_step_back_fails_and_a_frozen_stream_goes_stale():
    source, simulator = _source(stale_after=0.2)
    first = encode_fields(time.time(), 5, {"broken": False})
    source.deliver(first)
    assert _after(source, simulator, 0.05)[1] == OK
    for _ in range(2):  # the same message again (a retransmission, a frozen stream): refused, never taken
        source.deliver(first)
        assert _after(source, simulator, simulator.get_context().get_time() + 0.04)[1:].tolist() == [OK, 0.0]
    assert source.rejected == 2
    # an older sequence number with other content: not this sender's stream (another sender, or a replay)
    source.deliver(encode_fields(time.time(), 4, {"broken": True}))
    assert _after(source, simulator, simulator.get_context().get_time() + 0.04)[1] == CORRUPT
    assert source.rejected == 3
    assert _after(source, simulator, 0.6)[1] == STALE  # nothing since: stale by the receiver's clock


def test_freshness_is_the_receivers_a_stamp_from_the_future_is_refused_and_a_late_one_is_stale():
    source, simulator = _source(stale_after=0.2)
    source.deliver(encode_fields(time.time() + 1e6, 1, {"broken": False}))  # a million seconds ahead
    assert _after(source, simulator, 0.05)[1] == STALE and source.rejected == 1
    source.deliver(encode_fields(time.time(), 2, {"broken": False}))
    assert _after(source, simulator, 0.09)[1] == OK  # the future one did not poison the sequence or the clock
    source.deliver(encode_fields(time.time() - 1.0, 3, {"broken": False}))  # taken a second ago: late
    assert _after(source, simulator, 0.13)[1] == STALE


def test_malformed_payloads_make_the_link_corrupt_and_trust_returns_after_recover_after_good_ones():
    source, simulator = _source(recover_after=3)
    t = 0.0
    seq = 0

    def send(payload_of_seq) -> float:
        nonlocal t, seq
        seq += 1
        source.deliver(payload_of_seq(seq))
        t += 0.04
        return _after(source, simulator, t + 0.01)[1]

    good = lambda n: encode_fields(time.time(), n, {"broken": False})  # noqa: E731
    assert [send(good) for _ in range(3)] == [RECOVERING, RECOVERING, OK]  # the very first ones too
    deep = b"[" * 100_000 + b"]" * 100_000
    for bad in (b"not json", deep, json.dumps({"t": 10 ** 400, "seq": 1, "fields": {}}).encode(),
                json.dumps({"t": time.time(), "seq": 10 ** 400, "fields": {"broken": False}}).encode(),
                encode_fields(time.time(), 99, {"broken": "yes"})):
        assert send(lambda n, bad=bad: bad) == CORRUPT
        assert send(good) == RECOVERING
    assert [send(good) for _ in range(2)] == [RECOVERING, OK]


def test_each_kind_of_refusal_is_logged_the_first_time_it_comes_then_counted(caplog):
    """An oversized message is logged; a deeply nested one and a future-stamped one after it are logged too
    (each a kind of its own), where only the counts 1, 10, 100 used to be; more of a kind are counted."""
    import logging

    source, simulator = _source()
    seq = iter(range(1, 1000))
    oversized = b"[" + b"0," * 40_000 + b"0]"
    nested = b"[" * 30_000 + b"]" * 30_000  # under the size limit, past any depth
    future = encode_fields(time.time() + 1e6, next(seq), {"broken": False})
    with caplog.at_level(logging.WARNING, logger="cellsim.live"):
        for payload in (oversized, nested, future, oversized, oversized):
            source.deliver(payload)
        _after(source, simulator, 0.1)
    refusals = [r.getMessage() for r in caplog.records if "refused a message" in r.getMessage()]
    assert source.rejected == 5
    assert len(refusals) == 3, refusals
    assert "more than the" in refusals[0] and "nested too deeply" in refusals[1] and "(future)" in refusals[2]


def test_an_entitys_commands_are_looked_at_as_often_as_its_supervisors_or_its_twin_mode_can_change_them():
    """The command publisher looks one step after each update that could change a command: the common divisor of
    the entity's period and its supervisors' (the harm service's plant-rate updates drive no command)."""
    from cellsim.api import build, load_scenario
    from cellsim.diagrams.cell import _decided_every

    seen = {}

    def extend(cell):
        for name, entity in cell.entities.items():
            seen[name] = _decided_every(cell.builder, entity, cell.scenario.time_step)

    from conftest import ROOT

    build(load_scenario(ROOT / "scenarios" / "welding_cell.yaml"), extend=extend)
    # the robot and the welder: the safety controller's 20 ms (with the process controller's 40 ms)
    assert seen == {"robot": 0.02, "welder": 0.02, "operator": 0.02, "light_barrier": 0.04, "range_detector": 0.04}


@contextlib.contextmanager
def _live_twin(*overrides: str):
    """The welding cell's live twin built in this process on an insecure loopback session, its simulator
    initialised; samples are handed to its sources directly (``source.deliver``)."""
    import zenoh
    from conftest import ROOT
    from live_processes import free_port

    from cellsim.api import load_scenario
    from cellsim.cell_io import Live
    from cellsim.diagrams.cell import build_cell
    from cellsim.live.session import session_config
    from cellsim.simulation import make_simulator

    sf = load_scenario(ROOT / "scenarios" / "welding_cell.yaml", list(overrides))
    session = zenoh.open(session_config(role="twin", insecure=True, listen=[f"tcp/127.0.0.1:{free_port()}"],
                                        listen_by_default=True))
    cell = build_cell(sf, seed=0, duration=5.0, io=Live(session=session, wait_physical=5.0), record=False)
    try:
        simulator = make_simulator(cell)
        simulator.Initialize()
        sources = {s.get_name().partition(".")[0]: s for s in cell.network.primed}
        yield cell, simulator, sources
    finally:
        cell.close()
        session.close()


def test_a_live_twins_sensor_takes_a_sample_at_the_controllers_next_period_not_at_its_own():
    """The light barrier updates every 40 ms; in a live twin, in shadow mode, a sample that arrives is its reading
    at the next multiple of the safety controller's 20 ms (drained one step before), in phase with every entity
    (the controller decides on it one step later). The black box looks at its channels
    every 20 ms, so it keeps the reading from when it changed."""
    with _live_twin("light_barrier.twin.mode=shadow", "light_barrier.twin.recover_after=1") as (cell, simulator, sources):
        source, context = sources["light_barrier"], simulator.get_mutable_context()
        broken = cell.diagram.GetOutputPort("light_barrier.broken")
        assert cell.channels["light_barrier.broken"][0].period == 0.02  # recorded at the controller's rate
        assert cell.channels["robot.safety_mode"][0].period == 0.02  # the robot keeps its period
        source.deliver(encode_fields(time.time(), 1, {"broken": False}))
        cell.network.heard("light_barrier")
        cell.start(context)  # the clock starts; the source takes the sample that came before it
        simulator.AdvanceTo(0.002)
        assert broken.Eval(context)[0] == 0.0  # read from the start: no start-up spent failing safe
        simulator.AdvanceTo(0.121)
        source.deliver(encode_fields(time.time(), 2, {"broken": True}))  # between two of the barrier's updates
        simulator.AdvanceTo(0.1391)
        assert broken.Eval(context)[0] == 0.0  # drained at 0.138, not yet taken: every module changes on one grid
        simulator.AdvanceTo(0.1401)
        assert broken.Eval(context)[0] == 1.0  # taken at 0.14; its own update is at 0.16


def test_a_live_twins_controller_decides_on_the_samples_of_its_period_one_step_after_they_are_taken():
    """In a live twin the behaviours update one plant step after each multiple of their period, when the entities
    have taken what arrived: the safety controller detects the person the scanner reports at 0.142 s, not a period
    later, and commands the mitigation at its next update; each of its values is a channel whose updates are at
    that offset (the black box stamps them so)."""
    with _live_twin("range_detector.twin.mode=shadow", "range_detector.twin.recover_after=1") as (
            cell, simulator, sources):
        source, context = sources["range_detector"], simulator.get_mutable_context()
        controller = cell.modules["safety_controller"]
        assert controller.offset == 0.002 and cell.channels["safety_controller.HS"][0].offset == 0.002
        assert cell.modules["robot"].offset == 0.0  # entities keep the grid
        hazard = cell.diagram.GetOutputPort("safety_controller.HS")
        commanded = cell.diagram.GetOutputPort("safety_controller.safmod")
        phases, modes = controller.risk_model.phases.values, controller.risk_model.controlled["safmod"].values
        source.deliver(encode_fields(time.time(), 1, {"range": "far", "distance": 5.0}))
        cell.network.heard("range_detector")
        cell.start(context)
        simulator.AdvanceTo(0.121)
        assert phases[int(hazard.Eval(context)[0])] == "inact"
        source.deliver(encode_fields(time.time(), 2, {"range": "near", "distance": 1.5}))
        simulator.AdvanceTo(0.1415)
        assert phases[int(hazard.Eval(context)[0])] == "inact"  # taken at 0.14; the controller looks at 0.142
        simulator.AdvanceTo(0.1425)
        assert phases[int(hazard.Eval(context)[0])] == "act"
        assert modes[int(commanded.Eval(context)[0])] == "normal"
        simulator.AdvanceTo(0.1625)
        assert phases[int(hazard.Eval(context)[0])] == "mit"
        assert modes[int(commanded.Eval(context)[0])] == "ssmon"


def test_the_record_stamps_a_value_at_the_offset_update_that_wrote_it(tmp_path):
    """A module updated at an offset within its period (a live twin's controller): each change is recorded at
    the time of its update, and its initial value from 0 until the first update."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    import sqlite3

    from cellsim.blackbox import BlackBoxWriter
    from cellsim.channels import number_type
    from cellsim.recorder import Recorder
    from cellsim.systems import CellSystem

    class Counter(CellSystem):
        def __init__(self):
            super().__init__("counter", 0.02)
            self.n = self.declare_channel("n", number_type(None), 0.0)
            self.decide_after(0.002)

        def update(self, context, xd):
            xd.get_mutable_vector(self.n).SetAtIndex(0, context.get_discrete_state(self.n).GetAtIndex(0) + 1)

    builder = DiagramBuilder()
    counter = builder.AddSystem(Counter())
    recorder = Recorder(builder, "bb", counter.channels)
    simulator = Simulator(builder.Build())
    path = tmp_path / "bb.sqlite"
    writer = BlackBoxWriter(path)
    recorder.attach(writer)
    simulator.AdvanceTo(0.05)
    recorder.drain(simulator.get_context(), final=True)
    writer.close("complete")
    with contextlib.closing(sqlite3.connect(path)) as db:  # read back without cellsim
        rows = db.execute("SELECT t, payload FROM messages WHERE channel = 'counter.n' ORDER BY rowid").fetchall()
    assert [t for t, _ in rows] == pytest.approx([0.0, 0.002, 0.022, 0.042])
    assert [json.loads(p)["value"] for _, p in rows] == [0, 1, 2, 3]


def test_the_twin_measures_its_reaction_to_a_sample_and_reports_one_slower_than_the_scenario_assumes(capsys):
    """From a changed sample's stamp at its source to the commands decided on it going out: measured for each
    change of an entity in shadow or twin mode; one slower than assumed (here: stamped 150 ms before it came,
    against the light barrier's 40 ms + the safety controller's 20 ms) is counted, said once on stderr, and in
    the status and the black box's figures. Samples that only repeat, and entities in model mode, measure nothing."""
    with _live_twin("light_barrier.twin.mode=shadow", "light_barrier.twin.recover_after=1",
                    "welder.twin.recover_after=1") as (cell, simulator, sources):
        source, context = sources["light_barrier"], simulator.get_mutable_context()
        watch = cell.diagram.GetSubsystemByName("reaction_watch")
        assert watch.assumed["light_barrier"].seconds == pytest.approx(0.06)
        source.deliver(encode_fields(time.time(), 1, {"broken": False}))
        cell.network.heard("light_barrier")
        cell.start(context)
        simulator.AdvanceTo(0.101)
        source.deliver(encode_fields(time.time(), 2, {"broken": False}))  # no change: nothing to react to
        for seq, mode in enumerate(("normal", "stopped"), 1):  # the welder changes, but is in model mode
            sources["welder"].deliver(encode_fields(time.time(), seq, {"safety_mode": mode, "activity": "off"}))
        simulator.AdvanceTo(0.2)
        assert watch.counts["light_barrier"] == 0 and cell.diagram.GetOutputPort("welder.physical_link").Eval(
            context)[0] == PhysicalLink.UNUSED.code
        sent = time.time()
        source.deliver(encode_fields(sent, 3, {"broken": True}))
        simulator.AdvanceTo(0.3)
        figures = watch.figures()["light_barrier"]
        assert figures["count"] == 1 and figures["exceeded"] == 0 and 0.0 < figures["max"] <= time.time() - sent
        source.deliver(encode_fields(time.time() - 0.15, 4, {"broken": False}))  # 150 ms on its way
        simulator.AdvanceTo(0.4)
        figures = cell.network.metadata()["reaction_s"]["light_barrier"]
        assert figures["count"] == 2 and figures["exceeded"] == 1 and figures["max"] > 0.15
        assert watch.status()["slower"] == ["light_barrier"]
        assert "light_barrier: sample -> decision" in capsys.readouterr().err
        assert watch.counts["welder"] == 0  # in model mode its samples decide nothing: no reaction to measure
        # the run's summary names it as a finding, from the black box's metadata
        from types import SimpleNamespace

        from cellsim.cli.simulate import findings_lines
        from cellsim.live.reaction import reaction_findings

        found = reaction_findings({"live": cell.network.metadata()})
        assert [(f.subject, f.what) for f in found] == [("light_barrier", "slow reaction")]
        assert 0.3 <= found[0].start <= 0.4 and found[0].data["exceeded"] == 1
        (label, text), = findings_lines(SimpleNamespace(findings=found, waived={}))
        assert label == "slow reaction" and "1 of 2 changed samples decided on slower than the 60 ms" in text


def test_a_flood_is_dropped_unread_and_the_link_fails_safe_for_the_period_then_recovers():
    """The audit's case: a drain read its inbox until it was empty, so a sender publishing faster than messages are
    judged kept one update running for good (the twin stopped pacing and publishing). A drain takes only what waited
    when it began; more than FLOOD of them is a flood: dropped unread, the link stale for the period."""
    from cellsim.live.systems import FLOOD

    source, simulator = _source()
    now = time.time()
    source.deliver(encode_fields(now, 1, {"broken": False}))
    assert _after(source, simulator, 0.05)[1:].tolist() == [OK, 0.0]
    flood = encode_fields(now, 2, {"broken": True})
    for _ in range(FLOOD + 1):
        source.deliver(flood)
    assert _after(source, simulator, 0.09)[1] == STALE and source.rejected == 1
    assert source.inbox.waiting() == 0  # (dropped, not left for the next drain)
    source.deliver(encode_fields(time.time(), 3, {"broken": True}))
    assert _after(source, simulator, 0.13)[1:].tolist() == [OK, 1.0]
    source.deliver(encode_fields(time.time(), 4, {"broken": False}))
    source.deliver(encode_fields(time.time(), 5, {"broken": True}))
    assert _after(source, simulator, 0.17)[1:].tolist() == [OK, 1.0]  # (up to FLOOD waiting: every one taken)


def test_a_failure_message_refused_for_its_stamp_or_its_order_is_counted_as_refused():
    """The audit's: a failure message from the future, or repeated, was refused without a word or a count."""
    source, simulator = _source()
    now = time.time()
    source.deliver(encode_fields(now, 1, {"broken": False}))
    assert _after(source, simulator, 0.05)[1] == OK
    source.deliver(encode_failure(now + 1e6, 2, Fault.CRC))  # stamped a million seconds ahead: refused
    assert _after(source, simulator, 0.09)[1] == OK and source.rejected == 1
    failure = encode_failure(now, 3, Fault.CRC)
    source.deliver(failure)  # the link's failure, taken
    source.deliver(failure)  # the same again: refused
    assert _after(source, simulator, 0.13)[1] == CORRUPT and source.rejected == 2


def test_a_twin_behind_the_wall_sees_a_silent_sensor_stale_on_the_walls_clock():
    """An audit slowed a live twin 1.5-1.9 s behind the wall and silenced the light curtain: the twin saw it stale
    after 2.5 s (its simulated clock's stale_after, plus the lag), commanding the welder all along. The watchdog now
    judges a silence on the wall's clock too."""
    spec = SimpleNamespace(signal="broken", type=BOOL)
    entity = SimpleNamespace(module="light_barrier", sample_fields=("broken",), channels=[(spec, None)], period=0.04,
                             twin=SimpleNamespace(stale_after=0.5, recover_after=1))
    clock = LiveClock()
    clock.start()
    source = ZenohSampleSource(entity, clock, time_step=0.002)
    simulator = Simulator(source)  # not paced: as far behind as it falls
    simulator.Initialize()
    source.deliver(encode_fields(time.time(), 1, {"broken": False}))  # the curtain's last sample
    assert _after(source, simulator, 0.05)[1] == OK
    clock.mono_at_zero -= 1.0  # a second of the wall goes by that the twin does not simulate: it falls behind
    assert _after(source, simulator, 0.09)[1] == STALE  # 0.09 s of simulated time, but silent for a second


def test_a_twin_behind_the_wall_stamps_its_commands_with_the_time_it_decided_them():
    """The same audit found commands stamped when sent, so a twin 2 s behind the wall kept its devices on two-second-
    old decisions, each arriving 'fresh'. A command carries the wall time of the instant it was decided for, and a
    receiver's one link rule takes it as late."""
    from cellsim.codec import FieldCodec
    from cellsim.link import LinkTrust
    from cellsim.live.systems import CommandPublisher

    sent = []
    entity = SimpleNamespace(module="welder", command_fields=("activity",), input_types={"activity": BOOL})
    clock = LiveClock()
    clock.start()
    clock.mono_at_zero -= 2.0
    clock.wall_at_zero -= 2.0
    publisher = CommandPublisher(entity, SimpleNamespace(put=sent.append), 0.002, clock=clock)
    simulator = Simulator(publisher)  # not paced: as far behind as it is
    publisher.command_port.FixValue(simulator.get_mutable_context(), [1.0, 1.0])  # in twin mode, commanding 'true'
    simulator.AdvanceTo(0.05)
    assert len(sent) == 1  # decided at its first look, one plant step in
    message = FieldCodec.commands_of(entity).decode(sent[0])
    assert message.t == pytest.approx(clock.wall_at_zero + 0.002, abs=0.05)  # about 2 s before now
    trust = LinkTrust(timeout=0.5, recover_after=1)
    assert not trust.receive(0.0, message.seq, stamp=message.t, wall=time.time()).good


def test_a_commands_stamp_follows_a_step_of_the_hosts_wall_clock(monkeypatch):
    """A review found stamps taken as the wall at t = 0 plus t: a host clock stepped by NTP after the start (back a
    second, or on past stale_after) made every command read as from the future, or late, for good. The stamp is the
    wall's now less the lag measured on the monotonic clock: after a step it still differs from the receiver's wall
    by the lag alone."""
    import cellsim.live.systems as systems

    clock = LiveClock()
    clock.start()
    clock.mono_at_zero -= 0.3  # 0.3 s of the wall gone by, 0.1 s simulated: 0.2 s behind
    for step in (-1.0, 0.6):
        real = time.time
        monkeypatch.setattr(systems.time, "time", lambda step=step, real=real: real() + step)
        assert clock.wall_of(0.1) - systems.time.time() == pytest.approx(-0.2, abs=0.02)
        monkeypatch.undo()


def test_an_emulator_behind_the_wall_stamps_its_samples_as_old_as_they_are():
    """A review found the emulator stamping its samples when sent: one behind the wall reported old state as fresh,
    the pattern the twin's commands had. A device stamps a sample when it takes it; the emulator's Zenoh outlet stamps
    it with the wall time of its simulated instant, and the twin's one link rule takes an old one as late."""
    from cellsim.codec import loads, stamp
    from cellsim.link import LinkTrust
    from cellsim.live.emulator import ZenohOutlet

    sent = []
    clock = LiveClock()
    clock.start()
    clock.mono_at_zero -= 2.0  # 2 s of the wall gone by, the emulator at 0.1 s
    outlet = ZenohOutlet(SimpleNamespace(put=sent.append), wall_of=clock.wall_of)
    assert outlet.send({"broken": False}, None, 0.1) == 1
    t, seq = stamp(loads(sent[0]))
    assert time.time() - t == pytest.approx(1.9, abs=0.05)
    assert not LinkTrust(timeout=0.5, recover_after=1).receive(0.0, seq, stamp=t, wall=time.time()).good
