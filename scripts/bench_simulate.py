#!/usr/bin/env python3
"""Benchmark: 30 simulated seconds of the welding cell, headless, with recording,
against the bare robot plant with its joint controller over the same 30 s, measured
in the same run. Prints wall times, real-time factors, their ratio and peak memory.

Targets (issue 9): the cell at least 30x real time; at most 1.8x the bare plant's cost;
peak memory under 1 GiB. Issue 35: with the harm service on (every cell has it), at most
1.6x the bare plant; the black box's size per run is printed (messages and bytes).

Then, side by side in the same run (issue 23): the two-arm assembly bench against the same
bench with one arm (the assembler, its process and its speed and separation monitor taken
out, the loader's hand-over waits made dwells), per simulated second. Target: two robots
cost at most 2x one.

The bare plant is the arm as Drake parses its model, collision geometry included,
so the plant asks SceneGraph for contacts at every step. The cell's plant holds no
collision geometry (cellsim.kinds.robot.geometry: contact is measured, not
simulated), so the same arm without its collision elements is timed too, and the
cell's ratio to it printed, for a like-for-like view of cellsim's own overhead.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pydrake.multibody.parsing import Parser  # noqa: E402
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig  # noqa: E402
from pydrake.systems.analysis import Simulator  # noqa: E402
from pydrake.systems.controllers import InverseDynamicsController  # noqa: E402
from pydrake.systems.framework import DiagramBuilder  # noqa: E402
from pydrake.systems.primitives import TrajectorySource  # noqa: E402
from pydrake.trajectories import PiecewisePolynomial  # noqa: E402

from cellsim.kinds.robot.geometry import model_without_collision  # noqa: E402
from cellsim.kinds.robot.system import robot_base_pose  # noqa: E402
from cellsim.config.typed_yaml import ConfigError  # noqa: E402
from cellsim.scenario import load_scenario  # noqa: E402
from cellsim.simulation import integrate_at_plant_step, simulate  # noqa: E402
from cellsim.kinds.robot.system import KD, KI, KP  # noqa: E402

SCENARIO = ROOT / "scenarios" / "welding_cell.yaml"
TWO_ARMS = ROOT / "scenarios" / "assembly_bench.yaml"


def bare_plant_seconds(duration: float, overrides: list[str], contact_geometry: bool = True) -> float:
    """The same arm, plant configuration and joint controller, following the cell's poses."""
    sf = load_scenario(SCENARIO, overrides)
    cfg = sf.scenario.entities["robot"]
    model = str(sf.resolve_path("entities.robot.model", cfg.model))
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=sf.scenario.time_step, discrete_contact_approximation="sap", use_sampled_output_ports=False), builder)
    if contact_geometry:
        (arm,) = Parser(plant).AddModels(model)
    else:
        (arm,) = Parser(plant).AddModelsFromString(*model_without_collision(Path(model)))
    plant.WeldFrames(plant.world_frame(), plant.GetBodyByName("base_link", arm).body_frame(), robot_base_pose(cfg))
    plant.Finalize()
    control = MultibodyPlant(0.0)
    (carm,) = Parser(control).AddModels(model)
    control.WeldFrames(control.world_frame(), control.GetBodyByName("base_link", carm).body_frame(), robot_base_pose(cfg))
    control.Finalize()
    poses = [cfg.named_poses[p] for p in ("home", "shared_table", "weld_spot", "shared_table", "home")]
    times = np.linspace(0.0, duration, len(poses))
    source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.CubicShapePreserving(times, np.array(poses).T, True), 1))
    controller = builder.AddSystem(InverseDynamicsController(control, [KP] * 6, [KI] * 6, [KD] * 6, False))
    builder.Connect(plant.get_state_output_port(arm), controller.get_input_port_estimated_state())
    builder.Connect(source.get_output_port(), controller.get_input_port_desired_state())
    builder.Connect(controller.get_output_port_control(), plant.get_actuation_input_port(arm))
    simulator = Simulator(builder.Build())
    integrate_at_plant_step(simulator, plant.time_step())  # as the cell is simulated
    plant.SetPositions(plant.GetMyMutableContextFromRoot(simulator.get_mutable_context()), arm, poses[0])
    simulator.Initialize()
    start = time.perf_counter()
    simulator.AdvanceTo(duration)
    return time.perf_counter() - start


def cell_seconds(duration: float, seed: int, overrides: list[str]) -> tuple[float, int, int]:
    """Wall time of a recorded run of the welding cell, and its black box's messages and bytes."""
    import sqlite3

    sf = load_scenario(SCENARIO, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        summary = simulate(sf, Path(tmp) / "run", seed=seed, duration=duration)
        path = Path(tmp) / "run" / "blackbox.sqlite"
        db = sqlite3.connect(path)
        (messages,) = db.execute("SELECT count(*) FROM messages").fetchone()
        db.close()
        size = path.stat().st_size
    return summary.wall_time, messages, size


def one_arm_bench(folder: Path) -> Path:
    """The assembly bench with its assembler taken out: the loader alone, its hand-overs dwells."""
    import yaml

    data = yaml.safe_load(TWO_ARMS.read_text())
    del data["entities"]["assembler"]
    del data["behaviours"]["assembling"], data["behaviours"]["assembler_ssm"]
    controller = data["behaviours"]["safety_controller"]
    controller["commands"]["arm_mode"] = ["loader.safety_mode_request"]
    del controller["commands"]["assembler_task"]
    for step in data["behaviours"]["loading"]["steps"]:
        if "assembling" in str(step.get("wait_until", "")):
            del step["wait_until"]
            step["dwell"] = 1.0
    model = data["behaviours"]["safety_controller"]["risk_model"]
    risk = yaml.safe_load((TWO_ARMS.parent / model).read_text())
    del risk["controlled"]["assembler_task"]
    del risk["hazards"]["JAM"]["demands"]["act"]["assembler_task"]
    (folder / model).write_text(yaml.safe_dump(risk, sort_keys=False))
    data["entities"]["loader"]["model"] = str(TWO_ARMS.parent / data["entities"]["loader"]["model"])
    data["validation"] = {}
    path = folder / "one_arm_bench.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def per_simulated_second(path: Path, duration: float, seed: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        summary = simulate(load_scenario(path), Path(tmp) / "run", seed=seed, duration=duration)
    return summary.wall_time / summary.sim_time


def robots_figures(duration: float, repeats: int) -> None:
    """Two arms against one, alternated, per simulated second."""
    with tempfile.TemporaryDirectory() as tmp:
        one = one_arm_bench(Path(tmp))
        pairs = [(per_simulated_second(one, duration, seed), per_simulated_second(TWO_ARMS, duration, seed))
                 for seed in range(repeats)]
    one_arm = statistics.median(a for a, _ in pairs)
    two_arms = statistics.median(b for _, b in pairs)
    ratio = statistics.median(b / a for a, b in pairs)
    print(f"assembly bench, one arm  {one_arm * 1000:.1f} ms wall per simulated s  {1 / one_arm:6.1f}x real time")
    print(f"assembly bench, two arms {two_arms * 1000:.1f} ms wall per simulated s  {1 / two_arms:6.1f}x real time")
    print(f"two arms / one arm       {ratio:.2f}x  (pairs: {', '.join(f'{b / a:.2f}' for a, b in pairs)})   (target <= 2x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=5, help="median of this many runs of each, alternated")
    parser.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                        help="scenario override for both (repeatable), e.g. time_step=0.002")
    args = parser.parse_args()
    try:  # bad input: one line and exit code 2, as the CLI does
        load_scenario(SCENARIO, args.set)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    # alternate the two so that both see the same state of the machine; the ratio is
    # the median of each pair's ratio
    triples = [
        (bare_plant_seconds(args.duration, args.set), bare_plant_seconds(args.duration, args.set, contact_geometry=False),
         cell_seconds(args.duration, seed, args.set))
        for seed in range(args.repeats)
    ]
    boxes = [(messages, size) for _, _, (_, messages, size) in triples]
    triples = [(b, f, c) for b, f, (c, _, _) in triples]
    pairs = [(b, c) for b, _, c in triples]
    bare = statistics.median(b for b, _ in pairs)
    bare_free = statistics.median(f for _, f, _ in triples)
    cell = statistics.median(c for _, c in pairs)
    ratio = statistics.median(c / b for b, c in pairs)
    ratio_free = statistics.median(c / f for _, f, c in triples)
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"simulated time           {args.duration:.1f} s (median of {args.repeats})")
    print(f"bare plant + controller  {bare:.3f} s wall  {args.duration / bare:6.1f}x real time")
    print(f"  ... no contact geom.   {bare_free:.3f} s wall  {args.duration / bare_free:6.1f}x real time")
    print(f"welding cell, recorded   {cell:.3f} s wall  {args.duration / cell:6.1f}x real time   (target >= 30x)")
    print(f"cell / bare plant        {ratio:.2f}x  (pairs: {', '.join(f'{c / b:.2f}' for b, c in pairs)})   (target <= 1.6x with harm)")
    print(f"cell / bare, no contact  {ratio_free:.2f}x  (cellsim's own overhead, like for like)")
    print(f"peak memory              {peak_mib:.0f} MiB                               (target < 1024 MiB)")
    messages, size = boxes[0]
    print(f"black box per run        {messages} messages, {size / 1024:.0f} KiB per {args.duration:g} s")
    if not args.set:  # the overrides are the welding cell's
        robots_figures(args.duration, args.repeats)


if __name__ == "__main__":
    main()
