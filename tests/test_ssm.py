"""Speed and separation monitoring (ISO/TS 15066) and the two-arm assembly bench: the formula
against hand computations, the run where a person approaches moving arms, per-robot figures,
the arms' clearance, and the hand-over through wait_until."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from cellsim.kinds.ssm.system import SsmParameters
from cellsim.scenario import load_scenario
from cellsim.blackbox import BlackBox
from cellsim.simulation import simulate
from cellsim.validation.check import simulate_and_check

from conftest import ROOT

ASSEMBLY_BENCH = ROOT / "scenarios" / "assembly_bench.yaml"


def test_the_protective_distance_is_the_standards_sum_computed_by_hand():
    """S_p = v_h (T_r + T_s) + v_r T_r + v_r^2 / 2a + C + Z_d + Z_r, with T_s = v_r / a."""
    p = SsmParameters(human_speed=1.6, reaction_time=0.1, deceleration=2.5, intrusion_distance=0.1,
                      sensor_uncertainty=0.05, robot_uncertainty=0.02)
    # v_r = 0.5 m/s: T_s = 0.2 s; S_h = 1.6 * 0.3 = 0.48; S_r = 0.05; S_s = 0.25 / 5 = 0.05; C + Z = 0.17
    assert p.protective_distance(0.5) == pytest.approx(0.48 + 0.05 + 0.05 + 0.17, abs=1e-12)
    # standing still: the person's approach during the reaction time and the allowances
    assert p.protective_distance(0.0) == pytest.approx(0.16 + 0.17, abs=1e-12)
    # moving away counts as standing still (never a negative distance)
    assert p.protective_distance(-1.0) == p.protective_distance(0.0)
    # the speed limit is the speed whose S_p is the separation: 0.75 m allows exactly 0.5 m/s
    assert p.speed_limit(0.75) == pytest.approx(0.5, abs=1e-12)
    assert p.speed_limit(0.33) == 0.0 and p.speed_limit(0.1) == 0.0 and p.speed_limit(math.nan) == 0.0
    # a stop ordered 0.05 s ago: 0.05 s of reaction left; S_h = 1.6 * (0.05 + 0.2), S_r = 0.5 * 0.05
    assert p.protective_distance(0.5, reaction=0.05) == pytest.approx(0.4 + 0.025 + 0.05 + 0.17, abs=1e-12)
    # stopped, the reaction over: the allowances alone (a person may stand near a stopped arm)
    assert p.protective_distance(0.0, reaction=0.0) == pytest.approx(0.17, abs=1e-12)


def test_the_limit_leaves_room_for_the_persons_approach_over_the_latency():
    """L = 0.04 s (the monitor's and the robot's periods): the limit at d is the formula's at d - v_h L."""
    p = SsmParameters(human_speed=1.6, reaction_time=0.1, deceleration=2.5, intrusion_distance=0.1,
                      sensor_uncertainty=0.05, robot_uncertainty=0.02, latency=0.04)
    assert p.speed_limit(0.75 + 1.6 * 0.04) == pytest.approx(0.5, abs=1e-12)


def test_without_the_persons_motion_the_limit_is_the_published_formula():
    """v_max = sqrt((a T_r)^2 + 2 a (d - C)) - a T_r, computed by hand for d = 0.6 m, C = 0.1 m."""
    p = SsmParameters(human_speed=0.0, reaction_time=0.1, deceleration=2.5, intrusion_distance=0.1)
    by_hand = math.sqrt(0.25 ** 2 + 2 * 2.5 * 0.5) - 0.25  # 1.3507810593582121
    assert p.speed_limit(0.6) == pytest.approx(by_hand, abs=1e-12)
    assert p.protective_distance(by_hand) == pytest.approx(0.6, abs=1e-12)  # S_p(v_max) = d


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "run"
    done = simulate_and_check(load_scenario(ASSEMBLY_BENCH), out)
    return done, out


def _series(out, *names):
    with BlackBox(out / "blackbox.sqlite") as bb:
        return [bb.series(name) for name in names]


def test_a_person_approaching_the_moving_arms_lowers_their_speed_limits_and_the_arms_follow(bench_run):
    """Issue 23: the operator walks up to the fixture to clear a jam while the arms work: each ssm
    module's figures obey the formula at every sample, the limit falls under the ssmon cap as the
    person nears a moving arm, the arm's measured speed stays under it, and the margin stays >= 0."""
    from cellsim.kinds.ssm.system import parameters_of

    _, out = bench_run
    sf = load_scenario(ASSEMBLY_BENCH)
    slowed = 0
    for robot in ("loader", "assembler"):
        ssm = f"{robot}_ssm"
        params = parameters_of(sf.scenario.behaviours[ssm], sf.scenario.entities[robot])
        cap = sf.scenario.entities[robot].speed_limits.ssmon
        sep, protective, margin, limit, speed, mode = _series(
            out, f"{ssm}.separation", f"{ssm}.protective_distance", f"{ssm}.margin", f"{ssm}.speed_limit",
            f"{robot}.tool_speed", f"{robot}.safety_mode")
        assert len(sep.values) > 1000  # every control period
        for d, s_p, m, v in zip(sep.values, protective.values, margin.values, limit.values):
            assert v == pytest.approx(params.speed_limit(d), abs=2e-6)
            assert m == pytest.approx(d - s_p, abs=2e-6)
            assert s_p >= params.allowances - 1e-6
        assert min(margin.values) >= 0.0
        # the person came near: the limit fell well below the arm's ssmon cap (1 m/s)
        assert min(limit.values) < 0.5 and min(sep.values) < 1.0
        # in ssmon the measured tool speed never exceeds the limit in force 0.1 s before (reaction)
        limits = np.array(limit.values)
        times = np.array(limit.times)
        modes = list(zip(mode.times, mode.values))

        def mode_at(t):
            return ([v for u, v in modes if u <= t] or [None])[-1]

        for t, v in zip(speed.times, speed.values):
            if mode_at(t - 0.1) == "ssmon" and mode_at(t) == "ssmon" and v is not None:
                allowed = limits[(times >= t - 0.1) & (times <= t)].max()
                assert v <= min(allowed, cap) + 0.01, (robot, t, v, allowed)
                slowed += v > 0.05 and allowed < 0.5
    assert slowed > 0  # an arm did move near the person, slower than its cap, under a limit below it


def test_the_summary_labels_each_robots_figures(tmp_path):
    done = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(ASSEMBLY_BENCH), "--duration", "2",
                           "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=300, cwd=ROOT,
                          env={**os.environ, "COLUMNS": "120"})
    assert done.returncode == 0, done.stderr
    for label in ("work cycles completed (loader)", "work cycles completed (assembler)",
                  "final safety mode (loader)", "final safety mode (assembler)"):
        assert label in done.stdout
    assert "work cycles completed  " not in done.stdout  # no unlabelled line


def test_the_hand_over_keeps_the_arms_apart_and_without_it_they_meet(tmp_path, bench_run):
    """Ground truth's clearance between the two arms: above 20 cm through the wait_until hand-over;
    with both waits replaced by fixed dwells, the arms get out of step and meet at the fixture."""
    done, out = bench_run
    (clearance,) = _series(out, "ground_truth.clearance_loader_assembler")
    assert min(clearance.values) > 0.2 and max(clearance.values) > 0.8
    assert done.checked is not None  # its conditions were compiled and checked
    text = ASSEMBLY_BENCH.read_text().replace(
        "{name: await_fixture, wait_until: assembling.step == await_part, activity: waiting}",
        "{name: await_fixture, dwell: 0.1, activity: waiting}").replace(
        "{name: await_part, wait_until: loading.step == handed, activity: waiting}",
        "{name: await_part, dwell: 0.5, activity: waiting}")
    assert "dwell: 0.1" in text and "dwell: 0.5" in text
    path = ROOT / "scenarios" / f".test_no_handover_{os.getpid()}.yaml"
    path.write_text(text)
    try:
        out2 = tmp_path / "no_handover"
        simulate(load_scenario(path), out2, duration=25.0)
    finally:
        path.unlink()
    (clearance,) = _series(out2, "ground_truth.clearance_loader_assembler")
    assert min(clearance.values) < 0.2


def test_a_separation_sensor_must_be_a_distance(tmp_path):
    path = tmp_path / "bench.yaml"
    path.write_text(f"base: {ASSEMBLY_BENCH}\nbehaviours:\n  loader_ssm:\n    kind: ssm\n    robot: loader\n"
                    "    separation: scanner.field\n")
    done = subprocess.run([sys.executable, "-m", "cellsim", "scenario", "check", str(path)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "behaviours.loader_ssm.separation: 'scanner.field' is not a distance in m" in done.stderr


def test_a_reaction_time_shorter_than_the_monitor_and_robot_periods_is_refused_naming_the_key(tmp_path):
    """A review found T_r = 0 accepted: the arm takes a new limit only at its update after the monitor's, so the
    formula, the speed limit and the true margin credited 40 ms of reaction the arm does not have. One error line
    naming the file, line and key; exit 2; the periods' sum itself is accepted."""
    path = tmp_path / "bench.yaml"
    path.write_text(f"base: {ASSEMBLY_BENCH}\nbehaviours:\n  loader_ssm:\n    reaction_time: 0.03\n")
    done = subprocess.run([sys.executable, "-m", "cellsim", "scenario", "check", str(path)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "bench.yaml:4: behaviours.loader_ssm.reaction_time: 0.03 s is shorter than the periods of this monitor " \
           "and of robot 'loader' together (0.04 s)" in done.stderr, done.stderr
    path.write_text(f"base: {ASSEMBLY_BENCH}\nbehaviours:\n  loader_ssm:\n    reaction_time: 0.04\n")
    done = subprocess.run([sys.executable, "-m", "cellsim", "scenario", "check", str(path)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr


def test_a_robot_monitored_twice_is_refused_naming_both(tmp_path):
    path = tmp_path / "bench.yaml"
    path.write_text(f"base: {ASSEMBLY_BENCH}\nbehaviours:\n  again:\n    kind: ssm\n    robot: loader\n")
    done = subprocess.run([sys.executable, "-m", "cellsim", "scenario", "check", str(path)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2 and "robot 'loader' is already monitored by 'loader_ssm'" in done.stderr


def test_the_assembly_benchs_campaign_runs(tmp_path):
    done = subprocess.run([sys.executable, "-m", "cellsim", "campaign", str(ASSEMBLY_BENCH), "--runs", "3",
                           "--jobs", "2", "--duration", "5", "--out", str(tmp_path / "c"), "--quiet"],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode in (0, 1), done.stderr
    results = json.loads((tmp_path / "c" / "results.json").read_text())
    assert [r["status"] for r in results["runs"]] == ["completed"] * 3
    assert all({"loader", "assembler"} <= set(r["figures"]) for r in results["runs"])
    assert all(isinstance(r["figures"]["loader"]["cycles_completed"], int) for r in results["runs"])
    report = (tmp_path / "c" / "report.html").read_text()
    assert "Cycles completed per run (loader)" in report and "Cycles completed per run (assembler)" in report


def test_the_margin_condition_catches_arms_that_ignore_their_limit(tmp_path):
    """The same bench whose controller leaves the arms in normal (the limit applies only in ssmon):
    an arm works at full speed as the operator comes near, and G(margin >= 0) is violated."""
    from cellsim.validation.check import check

    model = (ROOT / "scenarios" / "assembly_bench_risk_model.yaml").read_text()
    assert "arm_mode: {values: [ssmon], default: ssmon}" in model
    (tmp_path / "unmonitored.yaml").write_text(model.replace("arm_mode: {values: [ssmon], default: ssmon}",
                                                             "arm_mode: {values: [normal], default: normal}"))
    path = tmp_path / "bench.yaml"
    path.write_text(f"base: {ASSEMBLY_BENCH}\nbehaviours:\n  safety_controller:\n    risk_model: unmonitored.yaml\n")
    simulate(load_scenario(path), tmp_path / "run", duration=20.0)  # both are violated well within 20 s
    verdicts = check(tmp_path / "run").result.verdicts
    assert not verdicts["AlwaysMonitored"].holds
    assert not (verdicts["LoaderMargin"].holds and verdicts["AssemblerMargin"].holds)


def test_in_ssmon_a_speed_limit_with_no_value_stops_the_arm():
    """The robot's speed_limit input fails safe: NaN is 0 m/s in ssmon, ignored in normal."""
    from cellsim.vocabulary import SafetyMode
    from cellsim.diagrams.cell import build_cell

    cell = build_cell(load_scenario(ASSEMBLY_BENCH), seed=0, duration=1.0, record=False)
    robot = cell.modules["loader"]
    motion = robot.start_segment(robot.poses[robot.pose_names.index("home")], robot.pose_names.index("bench_pick"))
    for mode, limit, moves in ((SafetyMode.SPEED_SEPARATION, math.nan, False), (SafetyMode.SPEED_SEPARATION, 0.0, False),
                               (SafetyMode.SPEED_SEPARATION, 0.3, True), (SafetyMode.NORMAL, math.nan, True)):
        state = motion
        for _ in range(10):
            state, _, _ = robot._advance(state, mode, state[0], limit)
        assert (state[1] > 0.0) == moves, (mode, limit)


@pytest.mark.parametrize("code", [float("nan"), -1.0, 99.0, "unknown"])
def test_a_mode_request_with_no_mode_an_arm_can_take_stops_the_arm(code):
    """A request the codec can carry but no arm can obey (no value, a code of no mode, ``unknown``: an emulated arm
    commanded by the twin) stops the arm, as a machine does, rather than stop the run."""
    from cellsim.diagrams.cell import build_cell
    from cellsim.kinds.robot.system import requested_mode
    from cellsim.vocabulary import SafetyMode

    if code == "unknown":
        code = float(SafetyMode.UNKNOWN.code)
    assert requested_mode(code) is SafetyMode.STOPPED
    assert requested_mode(float(SafetyMode.SPEED_SEPARATION.code)) is SafetyMode.SPEED_SEPARATION
    cell = build_cell(load_scenario(ASSEMBLY_BENCH), seed=0, duration=1.0, record=False)
    robot = cell.modules["loader"]
    state = robot.start_segment(robot.poses[robot.pose_names.index("home")], robot.pose_names.index("bench_pick"))
    for _ in range(10):
        state, _, _ = robot._advance(state, requested_mode(code), state[0], 1.0)
    assert state[1] == 0.0  # it has not left its pose


def test_a_robot_in_twin_mode_sends_its_physical_twin_the_ssm_limit_in_force_and_the_cap_without_one():
    """The SSM monitor's speed_limit is a command of the robot: what the physical controller is told (a UR's speed
    slider), at most the ssmon cap; a cell with no ssm sends the cap (an unlimited speed is no number a message
    carries), and a lost supervisor's safe command allows no speed."""
    from cellsim.api import build, load_scenario
    from cellsim.simulation import make_simulator
    from conftest import ROOT

    cell = build(load_scenario(ROOT / "scenarios" / "machine_tending.yaml",
                               ["robot.twin.mode=twin", "robot.speed_limits.ssmon=1.0"]))  # the monitor goes below it
    robot = cell.entity("robot")
    at = list(robot.command_fields).index("speed_limit") + 1
    simulator = make_simulator(cell)
    context = simulator.get_mutable_context()
    limit, command = cell.diagram.GetOutputPort("ssm.speed_limit"), cell.diagram.GetOutputPort("robot.physical_command")
    seen = set()
    for t in np.arange(0.5, 12.0, 0.5):
        simulator.AdvanceTo(t)
        sent = command.Eval(context)
        assert sent[0] == 1.0 and sent[at] == pytest.approx(min(limit.Eval(context)[0], 1.0)), t
        seen.add(round(sent[at], 3))
    assert 1.0 in seen and min(seen) < 0.7  # it follows the monitor as the person comes near and goes
    assert robot.safe_command()["speed_limit"] == 0.0
    welding = build(load_scenario(ROOT / "scenarios" / "welding_cell.yaml", ["robot.twin.mode=twin"]))
    context = welding.diagram.CreateDefaultContext()
    welding.set_initial_state(context)
    sent = welding.diagram.GetOutputPort("robot.physical_command").Eval(context)
    assert sent[at] == 0.5  # no ssm module: its input reads unlimited, the ssmon cap goes out


def test_on_the_geometry_a_lost_link_of_a_person_or_the_robot_reads_no_separation_and_stops_the_arm():
    """The separation on the geometry is between digital bodies: one whose physical link is not ok holds a pose the
    real one may have left. A person tracked from 6 s (shadow) whose samples never come: the model run's limit falls
    as they come near, but the lost one's must not hold the last pose's limit: it reads 0 from the first update
    the stale link is seen. A robot in twin mode whose samples never come is told no speed."""
    from cellsim.api import build
    from cellsim.config.twin import TwinModeChange
    from cellsim.simulation import make_simulator
    from cellsim.vocabulary import PhysicalLink, TwinMode

    def limits(sf, entity: str, times):
        cell = build(sf)
        simulator = make_simulator(cell)
        simulator.Initialize()
        context = simulator.get_mutable_context()
        limit = cell.diagram.GetOutputPort("assembler_ssm.speed_limit")
        margin = cell.diagram.GetOutputPort("loader_ssm.margin" if entity == "loader" else "assembler_ssm.margin")
        link = cell.diagram.GetOutputPort(f"{entity}.physical_link")
        command = cell.diagram.GetOutputPort("loader.physical_command")
        at = list(cell.entity("loader").command_fields).index("speed_limit") + 1
        found = []
        for t in times:
            simulator.AdvanceTo(t)
            found.append((PhysicalLink.from_code(int(link.Eval(context)[0])), limit.Eval(context)[0],
                          command.Eval(context)[at]))
            # no separation measured: no margin either (a condition on it undecided, not violated by a stopped arm)
            assert math.isnan(margin.Eval(context)[0]) == (found[-1][0] is PhysicalLink.STALE), t
        return found

    times = (5.0, 12.0, 19.0)
    tracked = load_scenario(ASSEMBLY_BENCH, ["duration=20"])
    model = limits(tracked, "operator", times)
    tracked.scenario.entities["operator"].twin.changes = [TwinModeChange(at=6.0, mode=TwinMode.SHADOW)]
    lost = limits(tracked, "operator", times)
    assert model[0] == lost[0] and model[0][1] > 0.5  # nobody near at 5 s: the same limit, the link unused
    assert all(m[1] > 0.0 for m in model)  # the real person near, as the model run shows: a limit above 0 there
    assert [(link, limit) for link, limit, _ in lost[1:]] == [(PhysicalLink.STALE, 0.0)] * 2

    arm_lost = limits(load_scenario(ASSEMBLY_BENCH, ["duration=20", "loader.twin.mode=twin"]), "loader", (2.0, 8.0))
    assert [(link, sent) for link, _, sent in arm_lost] == [(PhysicalLink.STALE, 0.0)] * 2


# A person clearing the jam steps back into the approach field and in again (as in the witness with which
# `cellsim verify` found the fault and the twin confirmed it): the field is never clear, so JAM stays active.
IN_OUT_AND_IN = """\
base: {base}
duration: 9.0
entities:
  operator:
    start: [1.6, -1.2]
    start_delay: 1.0
    speed_jitter: 0.0
    waypoints: !replace
      jam: {{position: [0.8, 0.0], wait: 1.0}}
      approach: {{position: [0.8, -0.9], wait: 0.5}}
      jam_again: {{position: [0.8, 0.0], wait: 2.0}}
configuration_points: !replace {{}}
campaign: !replace {{}}
"""


@pytest.mark.parametrize("waits_on", ["its controller", "its own condition"])
def test_each_arm_yields_for_as_long_as_its_controller_demands_it(tmp_path, waits_on):
    """Each arm's process waits, yielding, until the safety controller releases it. With the first version's own
    weaker condition (field not jam) the assembler went back to waiting while JAM was still active, and a person
    stepping in again found it so: JamYields violated."""
    path = tmp_path / "in_out_and_in.yaml"
    path.write_text(IN_OUT_AND_IN.format(base=ASSEMBLY_BENCH))
    steps = load_scenario(ASSEMBLY_BENCH).scenario.behaviours["assembling"].steps
    wait_free = next(i for i, step in enumerate(steps) if step.name == "wait_free")
    assert steps[wait_free].wait_until == "safety_controller.assembler_task != yielding"
    overrides = [] if waits_on == "its controller" else [
        f"behaviours.assembling.steps.{wait_free}.wait_until=scanner.field != jam"]
    done = simulate_and_check(load_scenario(path, overrides), tmp_path / "run", seed=0)
    verdicts = {name: v.status.name for name, v in done.checked.result.verdicts.items()}
    assert done.summary.hazards["safety_controller.JAM"].raised == 1  # one stint, the field never clear between
    assert verdicts["JamYields"] == ("HOLDS" if waits_on == "its controller" else "VIOLATED")


def test_a_stale_sensor_gives_the_monitor_no_separation_and_a_stopped_arm_no_margin_violation(tmp_path):
    """An audit found a stale scanner (read as 0 m, failing safe) giving the monitor a separation of 0 and a margin of
    -S_p, so SensedMargin was violated for the whole outage by an arm standing still. The monitor now takes its sensor's
    reading as no value while the sensor's link is not ok; the machine-tending cell's SensedMargin is written as what
    the sensed margin must never show (not margin < 0)."""
    sf = load_scenario(ROOT / "scenarios" / "machine_tending.yaml", ["entities.scanner.twin.mode=shadow"])
    done = simulate_and_check(sf, tmp_path / "stale", seed=0, duration=4.0)
    with BlackBox(tmp_path / "stale" / "blackbox.sqlite") as bb:
        assert set(bb.series("scanner.physical_link").values) == {"stale"}  # from the start, throughout
        separation = bb.series("ssm.separation")
        assert all(v is None for t, v in zip(separation.times, separation.values) if t > 0.0)
        limit, speed = bb.series("ssm.speed_limit"), bb.series("robot.tool_speed")
        assert all(v == 0.0 for t, v in zip(limit.times, limit.values) if t > 0.0)
        assert max(v for t, v in zip(speed.times, speed.values) if t > 1.0) < 0.01  # the arm stands still
    verdicts = {name: v.status.value for name, v in done.checked.result.verdicts.items()}
    assert verdicts["SensedMargin"] == "holds", verdicts


@pytest.mark.parametrize("cell", ["welding_cell", "machine_tending"])
def test_the_default_deceleration_is_what_the_arm_brakes_at_its_paths_fastest_point(cell):
    """An audit found the default deceleration, speed_limits.normal / braking_time (2.0 m/s^2), above what the arm
    delivers: it plans 0.04 m/s below the cap and its path's speed 5 % over its samples, so it brakes at 1.83 at the
    path's fastest point. The default is now that, on every segment between named poses the normal cap limits, and
    a segment its joints limit brakes slower (docs/ssm.md)."""
    from cellsim.diagrams.cell import build_cell
    from cellsim.kinds.robot.system import PATH_MARGIN, braking_deceleration
    from cellsim.kinds.ssm.system import parameters_of

    sf = load_scenario(ROOT / "scenarios" / f"{cell}.yaml")
    robot = build_cell(sf, seed=0, duration=1.0, record=False).modules["robot"]
    a = braking_deceleration(robot.cfg)
    assert a == pytest.approx((robot.cfg.speed_limits.normal - 0.04) / (1.05 * robot.cfg.braking_time))
    for module in sf.scenario.behaviours.values():
        if getattr(module, "kind", None) == "ssm" and module.deceleration is None:
            assert parameters_of(module, robot.cfg).deceleration == a
    delivered = []
    for i in range(len(robot.poses)):
        for j in range(len(robot.poses)):
            if i != j:
                _, _, _, tool_per_s, joint_rate = robot.start_segment(robot.poses[i], j)[:5]
                full = min(joint_rate, (robot.cfg.speed_limits.normal - 0.04) / tool_per_s)  # the planner's ds/dt
                delivered.append(full / robot.cfg.braking_time * tool_per_s / PATH_MARGIN)  # at the fastest point
    assert min(delivered) <= a + 1e-9 and max(delivered) == pytest.approx(a)  # none brakes harder; where the cap limits, a
