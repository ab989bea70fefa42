"""Running a scenario headless: build, simulate, record, summarise.

``simulate`` checks and builds everything before it touches the output folder,
so bad input leaves nothing behind. The output folder then holds

* ``blackbox.sqlite``: every message (see ``cellsim.services.blackbox``);
* ``scenario.yaml``: the resolved scenario, which re-runs the same run.

A run is a pure function of the scenario and the seed: the same inputs give
identical ``messages`` rows.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

from cellsim.config.typed_yaml import to_data
from cellsim.scenario import ScenarioFile, export_scenario
from cellsim.services.blackbox import BlackBox, BlackBoxWriter
from cellsim.services.recorder import DRAIN_SAMPLES
from diagrams.cell import CellDiagram, build_cell

BLACKBOX = "blackbox.sqlite"
RESOLVED_SCENARIO = "scenario.yaml"


class OutputExistsError(Exception):
    """The output folder already holds a run."""


@dataclass
class HazardCounts:
    raised: int = 0
    mitigated: int = 0
    mishaps: int = 0


@dataclass
class RunSummary:
    out_dir: Path
    seed: int
    status: str
    sim_time: float
    wall_time: float
    cycles_completed: int
    hazards: dict[str, HazardCounts] = field(default_factory=dict)
    final_safety_mode: str | None = None

    @property
    def real_time_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")

    @property
    def mishap(self) -> bool:
        return any(h.mishaps for h in self.hazards.values())


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for package in ("cellsim", "drake", "numpy", "pyyaml", "rich"):
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def prepare_output(out_dir: Path, overwrite: bool = False) -> None:
    """Make sure ``out_dir`` can take a new run without losing an old one."""
    blackbox = out_dir / BLACKBOX
    if blackbox.exists():
        if not overwrite:
            raise OutputExistsError(f"{out_dir} already holds a run ({BLACKBOX}); choose another --out or pass --overwrite")
        for name in (BLACKBOX, BLACKBOX + "-wal", BLACKBOX + "-shm", RESOLVED_SCENARIO):
            (out_dir / name).unlink(missing_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)


def simulate(
    sf: ScenarioFile,
    out_dir: str | os.PathLike,
    *,
    seed: int | None = None,
    duration: float | None = None,
    overwrite: bool = False,
    meshcat=None,
    realtime_rate: float = 0.0,
    physical_sources: dict | None = None,
    on_progress: Callable[[float, float], None] | None = None,
) -> RunSummary:
    """Simulate ``sf`` headless (or at ``realtime_rate``), recording to ``out_dir``."""
    sc = sf.scenario
    seed = sc.seed if seed is None else seed
    duration = sc.duration if duration is None else duration
    out_dir = Path(out_dir)

    # Everything that can fail on bad input happens before the folder is touched:
    # building the diagram checks the wiring and loads the risk model.
    cell = build_cell(sf, seed=seed, duration=duration, meshcat=meshcat, physical_sources=physical_sources)
    simulator = make_simulator(cell, realtime_rate)
    prepare_output(out_dir, overwrite)
    resolved = export_scenario(sf, destination_dir=out_dir)
    tmp = out_dir / (RESOLVED_SCENARIO + ".tmp")
    tmp.write_text(resolved)
    tmp.replace(out_dir / RESOLVED_SCENARIO)

    recorder_cfg = next(iter(sc.modules_of_kind("blackbox").values()), None)
    writer = BlackBoxWriter(out_dir / BLACKBOX, batch_size=recorder_cfg.batch_size if recorder_cfg else 5000)
    status = "failed"
    started = time.perf_counter()
    context = simulator.get_mutable_context()
    sim_time = 0.0
    try:
        if cell.recorder is not None:
            cell.recorder.attach(writer)
        writer.set_metadata(
            scenario=to_data(sc),
            scenario_name=sc.name,
            scenario_source=str(sf.source),
            overrides=sf.overrides,
            seed=seed,
            duration=duration,
            versions=package_versions(),
            status="running",
        )
        simulator.Initialize()
        started = time.perf_counter()
        try:
            step = 1.0
            while context.get_time() < duration - 1e-9:
                simulator.AdvanceTo(min(duration, context.get_time() + step))
                sim_time = context.get_time()
                if cell.recorder is not None:
                    cell.recorder.drain(context, min_samples=DRAIN_SAMPLES)
                if on_progress:
                    on_progress(sim_time, duration)
            status = "completed"
        except KeyboardInterrupt:
            status = "interrupted"
            raise
    finally:
        wall = time.perf_counter() - started
        if cell.recorder is not None:
            cell.recorder.drain(context)  # what was logged before an interruption
        writer.close(status)
    return summarise(out_dir, seed, status, sim_time, wall)


def make_simulator(cell: CellDiagram, realtime_rate: float = 0.0) -> Simulator:
    """A simulator of ``cell`` at its initial state; call ``Initialize()`` once recording is attached."""
    simulator = Simulator(cell.diagram)
    integrate_at_plant_step(simulator, cell.plant.time_step())
    cell.set_initial_state(simulator.get_mutable_context())
    simulator.set_target_realtime_rate(realtime_rate)
    return simulator


def integrate_at_plant_step(simulator: Simulator, time_step: float) -> None:
    """Integrate the continuous state with explicit Euler, one step per plant step.

    The only continuous state of a cell is its joint controllers' PID integral,
    whose derivative (desired minus measured joint position) is constant between
    plant steps, since every discrete event falls on a multiple of the plant
    step. Explicit Euler at that step integrates it exactly, with one derivative
    evaluation per step where the default error-controlled RK3 makes three.
    """
    ResetIntegratorFromFlags(simulator, "explicit_euler", time_step)
    simulator.get_mutable_integrator().set_fixed_step_mode(True)


def summarise(out_dir: Path, seed: int, status: str, sim_time: float, wall_time: float) -> RunSummary:
    """Read a run's summary back from its black box."""
    with BlackBox(out_dir / BLACKBOX) as bb:
        channels = bb.channels()
        summary = RunSummary(out_dir, seed, status, sim_time, wall_time, 0)
        for name, info in channels.items():
            if info.kind == "enum" and info.domain == ["inact", "act", "mit", "mit1", "mit2", "res", "mis"]:
                phases = bb.series(name).values
                summary.hazards[name.rpartition(".")[2]] = HazardCounts(
                    raised=phases.count("act"),
                    mitigated=sum(p in ("mit", "mit1", "mit2") for p in phases),
                    mishaps=phases.count("mis"),
                )
            elif name.endswith(".cycles_completed"):
                values = bb.series(name).values
                summary.cycles_completed = int(values[-1]) if values else 0
            elif name.endswith(".safety_mode") and info.source in _robots(bb):
                values = bb.series(name).values
                summary.final_safety_mode = values[-1] if values else None
    return summary


def _robots(bb: BlackBox) -> set[str]:
    scenario = bb.metadata().get("scenario", {})
    return {n for n, e in scenario.get("entities", {}).items() if e.get("kind") == "robot"}
