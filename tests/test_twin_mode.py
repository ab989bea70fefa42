"""Twin modes: what drives an entity's outputs, recorded; fail-safe on stale or corrupt data."""

from __future__ import annotations

import numpy as np

from cellsim.cell_io import Replayed
from cellsim.config.twin import TwinModeChange
from cellsim.vocabulary import PhysicalLink, TwinMode

from conftest import place_operator, run, welding_cell


def test_switch_model_to_shadow_mid_run_follows_the_physical_twin(tmp_path):
    recorded = run(place_operator(welding_cell(), start=(-4.0, -3.0)), tmp_path / "physical", duration=10.0)

    sf = place_operator(welding_cell(), start=(-4.0, -3.0))
    sf.scenario.entities["robot"].twin.changes = [TwinModeChange(4.0, TwinMode.SHADOW)]
    # the recorded run replayed as the robot's physical twin, two seconds late
    replay = Replayed(tmp_path / "physical" / "blackbox.sqlite", time_offset=2.0, entities=("robot",))
    bb = run(sf, tmp_path / "shadowed", duration=10.0, io=replay)

    mode = bb.series("robot.twin_mode")
    assert mode.values == ["model", "shadow"] and mode.times[1] == 4.0
    assert bb.series("robot.physical_link").value_at(5.0) == "ok"
    own, physical = bb.series("robot.joint_positions"), recorded.series("robot.joint_positions")
    for t in (1.0, 3.0):  # model mode: the digital behaviour, identical to the recorded run
        assert np.allclose(own.value_at(t), physical.value_at(t), atol=1e-6)
    # shadow mode: the hologram follows the physical twin (replayed two seconds late), within
    # a latency of at most 0.2 s (one update, 10 Hz samples, joint tracking) ...
    def error(t, physical_time):
        return np.max(np.abs(np.subtract(own.value_at(t), physical.value_at(physical_time))))

    for t in np.arange(6.0, 10.0, 0.25):
        assert min(error(t, t - 2.0 - latency) for latency in np.arange(0.0, 0.21, 0.02)) < 0.05
    # ... and no longer what its own digital behaviour does
    assert max(error(t, t) for t in np.arange(6.0, 10.0, 0.25)) > 1.0


def test_shadow_without_a_physical_twin_fails_safe(tmp_path):
    sf = place_operator(welding_cell(), start=(-4.0, -3.0))
    sf.scenario.entities["light_barrier"].twin.changes = [TwinModeChange(2.0, TwinMode.SHADOW)]
    sf.scenario.entities["range_detector"].twin.changes = [TwinModeChange(2.0, TwinMode.SHADOW)]
    bb = run(sf, tmp_path / "run", duration=4.0)
    assert bb.series("light_barrier.broken").value_at(1.9) is False
    assert bb.series("light_barrier.broken").value_at(2.1) is True
    assert bb.series("range_detector.range").value_at(2.1) == "close"
    assert bb.series("light_barrier.physical_link").value_at(2.1) == "stale"


def shadowed_range_detector(recover_after: int):
    """The welding cell's range detector shadowing its physical twin: (root context, system, its context)."""
    from cellsim.diagrams.cell import build_cell
    from pydrake.systems.analysis import Simulator

    sf = welding_cell()
    sf.scenario.entities["range_detector"].twin.mode = TwinMode.SHADOW
    sf.scenario.entities["range_detector"].twin.recover_after = recover_after
    built = build_cell(sf, seed=0, duration=1.0, record=False)
    sim = Simulator(built.diagram)
    context = sim.get_mutable_context()
    built.set_initial_state(context)
    rd = built.modules["range_detector"]
    return context, rd, rd.GetMyMutableContextFromRoot(context), sim


def test_corrupt_samples_fail_safe():
    _, rd, own, _sim = shadowed_range_detector(recover_after=1)  # each sample judged alone
    readings = {}
    samples = {"ok": [0.0, 1.0, 0.0, 2.5], "bad enum": [0.0, 1.0, 7.0, 2.5], "nan": [0.0, 1.0, 0.0, np.nan],
               "far at 0.2 m": [0.0, 1.0, 0.0, 0.2],  # the two fields disagree: one is wrong
               "near, rounded across": [0.0, 1.0, 1.0, rd.cfg.near_below + 0.001]}  # (a transport's rounding)
    for label, sample in samples.items():
        rd.physical_sample_port.FixValue(own, np.array(sample))
        state = rd.EvalUniquePeriodicDiscreteUpdate(own)
        readings[label] = (state.get_vector(rd.group("range")).GetAtIndex(0), state.get_vector(rd.group("physical_link")).GetAtIndex(0))
    assert readings["ok"] == (0.0, 1.0)  # far, link ok
    assert readings["bad enum"] == (2.0, 3.0)  # close, link corrupt
    assert readings["nan"] == (2.0, 3.0)
    assert readings["far at 0.2 m"] == (2.0, 3.0)
    assert readings["near, rounded across"] == (1.0, 1.0)  # near, link ok


def test_commands_go_out_only_in_twin_mode(tmp_path):
    from cellsim.diagrams.cell import build_cell
    from pydrake.systems.analysis import Simulator

    sf = welding_cell()
    sf.scenario.entities["welder"].twin.changes = [TwinModeChange(1.0, TwinMode.TWIN), TwinModeChange(2.0, TwinMode.SHADOW)]
    built = build_cell(sf, seed=0, duration=3.0, record=False)
    sim = Simulator(built.diagram)
    built.set_initial_state(sim.get_mutable_context())
    welder = built.modules["welder"]
    active = []
    for t in (0.5, 1.5, 2.5):
        sim.AdvanceTo(t)
        active.append(welder.physical_command_port.Eval(welder.GetMyContextFromRoot(sim.get_context()))[0])
    assert active == [0.0, 1.0, 0.0]


def test_leaving_twin_mode_from_a_script_silences_the_commands():
    from cellsim.diagrams.cell import build_cell
    from pydrake.systems.analysis import Simulator

    built = build_cell(welding_cell(), seed=0, duration=2.0, record=False)
    sim = Simulator(built.diagram)
    built.set_initial_state(sim.get_mutable_context())
    welder = built.entity("welder")

    def active():
        return welder.physical_command_port.Eval(welder.GetMyContextFromRoot(sim.get_context()))[0]

    welder.set_twin_mode(sim.get_mutable_context(), "twin")
    sim.AdvanceTo(0.5)
    assert active() == 1.0
    welder.set_twin_mode(sim.get_mutable_context(), "model")
    assert active() == 0.0
    sim.AdvanceTo(1.0)
    assert active() == 0.0


def test_set_twin_mode_from_a_script():
    from cellsim.diagrams.cell import build_cell
    from pydrake.systems.analysis import Simulator

    built = build_cell(welding_cell(), seed=0, duration=2.0, record=False)
    sim = Simulator(built.diagram)
    built.set_initial_state(sim.get_mutable_context())
    sim.AdvanceTo(0.5)
    built.entity("light_barrier").set_twin_mode(sim.get_mutable_context(), "shadow")
    sim.AdvanceTo(1.0)
    lb = built.entity("light_barrier")
    assert lb.twin_mode(sim.get_context()) is TwinMode.SHADOW
    assert lb.GetOutputPort("broken").Eval(lb.GetMyContextFromRoot(sim.get_context()))[0] == 1.0  # no sample: fails safe


def test_a_shadowed_robot_without_samples_reports_unknown_not_its_last_state(tmp_path):
    sf = place_operator(welding_cell(), start=(-4.0, -3.0))
    sf.scenario.entities["robot"].twin.changes = [TwinModeChange(2.0, TwinMode.SHADOW)]
    bb = run(sf, tmp_path / "run", duration=4.0)
    assert bb.series("robot.physical_link").value_at(2.1) == "stale"
    assert bb.series("robot.safety_mode").value_at(1.9) == "normal"
    for channel in ("robot.safety_mode", "robot.activity", "robot.location"):
        assert bb.series(channel).value_at(2.1) == "unknown", channel
    assert bb.series("robot.reached_pose").value_at(2.1) == "moving"
    assert bb.series("robot.joint_positions").value_at(2.2) == [None] * 6
    assert bb.series("robot.tool_speed").value_at(2.2) is None


def test_a_shadowed_robot_gone_silent_does_not_hide_a_person_in_the_cell(tmp_path, capsys):
    """Losing the robot's samples makes the cell safer: unknown counts as dangerous."""
    from cellsim.cli import main

    sf = welding_cell()  # the operator walks into the cell
    sf.scenario.entities["robot"].twin.mode = TwinMode.SHADOW
    bb = run(sf, tmp_path / "run", duration=30.0)
    assert set(bb.series("robot.safety_mode").values) == {"unknown"}
    hs = bb.series("safety_controller.HS")
    assert "act" in hs.values  # detected although the robot's mode and activity are unknown
    main(["check", str(tmp_path / "run"), "--json"])
    import json

    verdicts = json.loads(capsys.readouterr().out)["verdicts"]
    assert verdicts["HS:detected"]["status"] == "holds"


def test_an_entity_follows_the_link_its_source_judged():
    """The source judges the link (cellsim.link); the entity fails safe on anything but ok."""
    context, rd, own, _sim = shadowed_range_detector(recover_after=3)

    def step(link: PhysicalLink, code: float = 0.0) -> tuple[float, float]:
        rd.physical_sample_port.FixValue(own, np.array([0.0, float(link.code), code, 2.5]))
        own.SetDiscreteState(rd.EvalUniquePeriodicDiscreteUpdate(own))
        return rd.GetOutputPort("range").Eval(own)[0], rd.GetOutputPort("physical_link").Eval(own)[0]

    far, close = 0.0, 2.0
    for link in (PhysicalLink.STALE, PhysicalLink.CORRUPT, PhysicalLink.RECOVERING):
        assert step(link) == (close, float(link.code))
    assert step(PhysicalLink.OK) == (far, float(PhysicalLink.OK.code))
    assert step(PhysicalLink.OK, code=7.0) == (close, float(PhysicalLink.CORRUPT.code))  # ok, but not a range
    assert step(PhysicalLink.UNUSED) == (close, float(PhysicalLink.CORRUPT.code))  # no source says unused


def test_a_change_at_the_last_update_before_a_run_stops_is_recorded(tmp_path):
    """A run ending between two samples of a channel keeps what that channel's last update wrote."""
    sf = place_operator(welding_cell(), start=(-4.0, -3.0))
    sf.scenario.entities["light_barrier"].twin.changes = [TwinModeChange(1.0, TwinMode.SHADOW)]
    bb = run(sf, tmp_path / "run", duration=1.006)  # the curtain updates at 1.0; its next sample would be 1.04
    mode = bb.series("light_barrier.twin_mode")
    assert mode.values == ["model", "shadow"] and mode.times[1] == 1.0
    assert bb.series("light_barrier.physical_link").value_at(1.0) == "stale"


def test_a_replayed_physical_twin_that_ran_out_goes_stale_and_the_entity_fails_safe(tmp_path):
    """A recording of 3 s shadowed for 6: after its end its last values are no news (an audit found them held
    trusted forever). The link goes stale and the shadowed sensors read their safe values."""
    run(place_operator(welding_cell(), start=(-4.0, -3.0)), tmp_path / "physical", duration=3.0)
    sf = place_operator(welding_cell(), start=(-4.0, -3.0))
    for sensor in ("light_barrier", "range_detector"):
        sf.scenario.entities[sensor].twin.mode = TwinMode.SHADOW
    replay = Replayed(tmp_path / "physical" / "blackbox.sqlite", entities=("light_barrier", "range_detector"))
    bb = run(sf, tmp_path / "shadowed", duration=6.0, io=replay)
    link = bb.series("light_barrier.physical_link")
    assert link.value_at(2.0) == "ok" and link.value_at(4.0) == "stale"
    assert bb.series("light_barrier.broken").value_at(2.0) is False and bb.series("light_barrier.broken").value_at(4.0) is True
    assert bb.series("range_detector.range").value_at(4.0) == "close"
