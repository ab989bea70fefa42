"""Running a scenario headless: build, simulate, record, summarise.

``simulate`` checks and builds everything before it touches the output folder,
so bad input leaves nothing behind, and claims the folder for itself (see
:class:`RunFolder`). The output folder then holds

* ``blackbox.sqlite``: every message (see ``cellsim.blackbox``);
* ``scenario.yaml``: the resolved scenario, which re-runs the same run;
* ``inputs/``: copies of the files the run used (risk models, robot models),
  which ``scenario.yaml`` refers to, so the folder re-runs alone (see
  ``cellsim.provenance``).

A run is a pure function of the scenario and the seed: the same inputs give
identical ``messages`` rows.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

from cellsim.atomic import LOCK, FolderBusy, folder_lock
from cellsim.config.typed_yaml import to_data
from cellsim.provenance import BLACKBOX, INPUTS, RESOLVED_SCENARIO, package_versions, read_inputs, write_run_scenario
from cellsim.provenance import provenance as make_provenance
from cellsim.scenario import ScenarioFile
from cellsim.blackbox import BlackBox, BlackBoxWriter
from cellsim.recorder import DRAIN_PERIOD
from cellsim.cell_io import SIMULATED, CellIO
from cellsim.live.systems import TICK
from cellsim.systems import hazard_phases
from cellsim.diagrams.cell import CellDiagram, build_cell, scenario_for



class OutputExistsError(Exception):
    """The output folder already holds a run."""


@dataclass
class HazardCounts:
    raised: int = 0
    """Times the hazard left its initial phase (was detected)."""
    handled: int = 0
    """Times it came back to its initial phase."""
    mishaps: int = 0
    """Times it entered its mishap phase."""


@dataclass
class RobotFigures:
    """One robot's figures of a run."""

    cycles_completed: int = 0
    """Cycles completed by the process that moves it."""
    final_safety_mode: str | None = None

    def to_json(self) -> dict:
        return {"cycles_completed": self.cycles_completed, "final_safety_mode": self.final_safety_mode}


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
    robots: dict[str, RobotFigures] = field(default_factory=dict)
    """Each robot's figures, in the scenario's order (``cycles_completed`` and ``final_safety_mode``
    above are the first robot's, or the only one's)."""
    safety_case: object | None = None
    """The scenario's compiled validation (a ``SafetyCase``), when it has conditions."""

    @property
    def real_time_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")

    @property
    def mishap(self) -> bool:
        return any(h.mishaps for h in self.hazards.values())


RUN_FILES = (BLACKBOX, BLACKBOX + "-wal", BLACKBOX + "-shm", BLACKBOX + "-journal", RESOLVED_SCENARIO)


class RunFolder:
    """An exclusive claim on a run's output folder, held while the run is written.

    The claim is :func:`cellsim.atomic.folder_lock`: a second process that asks
    for the same folder is refused at once, and the lock goes with its holder
    however that ends, SIGKILL included. The folder must be new, empty, or hold a
    run (replaced only with ``overwrite``); the current folder is refused, so a
    run never mixes its files with the user's.
    """

    def __init__(self, out_dir: str | os.PathLike, overwrite: bool = False):
        self.path = Path(out_dir)
        self.overwrite = overwrite
        self._lock = contextlib.ExitStack()

    def __enter__(self) -> "RunFolder":
        out = self.path
        if str(out) in ("", ".") or (out.exists() and out.resolve() == Path.cwd().resolve()):
            raise OutputExistsError(f"--out '{out}' is the current folder; name a folder of its own for the run")
        if out.exists() and not out.is_dir():
            raise OutputExistsError(f"{out} is a file, not a folder; choose another --out")
        self._refuse_foreign(out)
        out.mkdir(parents=True, exist_ok=True)
        try:
            self._lock.enter_context(folder_lock(out))
        except FolderBusy:
            raise OutputExistsError(f"{out} is being written by another cellsim process; choose another --out") from None
        try:
            self._refuse_foreign(out)  # again, now that nobody else writes it
            if any((out / name).exists() for name in (BLACKBOX, RESOLVED_SCENARIO)):
                if not self.overwrite:
                    raise OutputExistsError(f"{out} already holds a run ({BLACKBOX}); choose another --out or pass --overwrite")
                for name in RUN_FILES:
                    (out / name).unlink(missing_ok=True)
                for extra in RUN_FOLDERS:
                    shutil.rmtree(out / extra, ignore_errors=True)
        except BaseException:
            self._lock.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self._lock.close()

    @staticmethod
    def _refuse_foreign(out: Path) -> None:
        """Refuse a folder holding files that no run wrote."""
        if not out.is_dir():
            return
        names = {p.name for p in out.iterdir()} - {LOCK}
        if names and not names & {BLACKBOX, RESOLVED_SCENARIO}:
            raise OutputExistsError(
                f"{out} is not empty and holds no run; choose a new or empty folder for --out"
            )


RUN_FOLDERS: tuple[str, ...] = (INPUTS,)
"""Sub-folders a run writes, removed with the run on ``overwrite``."""


def simulate(
    sf: ScenarioFile,
    out_dir: str | os.PathLike,
    *,
    io: CellIO = SIMULATED,
    seed: int | None = None,
    duration: float | None = None,
    overwrite: bool = False,
    meshcat=None,
    meshcat_wait: tuple | None = None,
    on_progress: Callable[[float, float], None] | None = None,
    provenance: dict | None = None,
) -> RunSummary:
    """Run ``sf`` with the I/O ``io`` (``cellsim.cell_io``: simulated by default), recording to ``out_dir``.

    One loop whatever the I/O: the builder decides what the physical side is and
    whether the run is paced to the wall clock; the network's work happens inside
    the diagram. A live or emulated run goes until ``duration`` or until it is
    stopped (Ctrl-C, SIGTERM): its record is then complete, ending there.
    ``meshcat_wait``: ``(seconds, say)`` to wait for a browser before simulated time runs.

    The black box's ``provenance`` metadata is :func:`cellsim.provenance.provenance`
    of the run's inputs, updated with ``provenance`` (a campaign names itself there).
    """
    from cellsim.scenario import check_run_length, check_seed

    sf = scenario_for(sf, io)  # an emulated cell runs its own version of the scenario, and records it
    sc = sf.scenario
    seed = sc.seed if seed is None else seed
    duration = sc.duration if duration is None else duration
    check_seed(seed, "seed")
    check_run_length(sf, duration, "duration" if duration == sc.duration else "--duration")
    out_dir = Path(out_dir)
    # -- provenance: the input files, read once; the run folder keeps copies of these bytes
    inputs = read_inputs(sf)
    record = make_provenance(inputs.identity(sf.overrides, seed, duration), **(provenance or {}))

    # Everything that can fail on bad input happens before the folder is touched:
    # building the diagram checks the wiring and loads the risk model, and the
    # safety conditions are compiled against the channels it publishes.
    cell = build_cell(sf, seed=seed, duration=duration, io=io, meshcat=meshcat, meshcat_wait=meshcat_wait)
    try:
        case = None
        if cell.sf.scenario.validation.conditions:
            from cellsim.validation.check import cell_safety_case

            case = cell_safety_case(cell.sf, cell)
        simulator = make_simulator(cell)
        inputs.check_unchanged()  # what was built is what was read, copied and hashed
        with RunFolder(out_dir, overwrite):
            summary = _record(cell, simulator, out_dir, seed, duration, on_progress, inputs, record)
    finally:
        cell.close()
    summary.safety_case = case
    return summary


def _record(cell, simulator, out_dir: Path, seed: int, duration: float, on_progress, inputs, record) -> RunSummary:
    """Write the resolved scenario and its input files, then simulate while recording the black box."""
    sf = cell.sf
    sc = sf.scenario
    write_run_scenario(sf, inputs, out_dir, RESOLVED_SCENARIO, seed, duration)

    writer = BlackBoxWriter(out_dir / BLACKBOX)
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
            provenance=record,
            hazards=hazard_phases(cell.modules.values()),
            status="running",
        )
        try:
            simulator.Initialize()
            cell.start()  # may wait for a browser, or for the physical cell
            simulator.ResetStatistics()  # real-time pacing counts from now
            started = time.perf_counter()
            # a paced run advances in short steps, so that Ctrl-C or SIGTERM lands between two of them,
            # in Python, with every message up to then recorded (not inside an event of the diagram)
            step = TICK if cell.runs_until_stopped else DRAIN_PERIOD
            next_drain = DRAIN_PERIOD
            while context.get_time() < duration - 1e-9:
                simulator.AdvanceTo(min(duration, context.get_time() + step, next_drain))
                sim_time = context.get_time()
                if sim_time < min(duration, next_drain) - 1e-9:
                    continue
                next_drain += DRAIN_PERIOD
                if cell.recorder is not None:
                    cell.recorder.drain(context)
                if cell.network is not None:
                    writer.set_metadata(**cell.metadata())
                if on_progress:
                    on_progress(sim_time, duration)
            status = "completed"
        except KeyboardInterrupt:
            # a live run goes until it is stopped: its record is then complete, ending now
            status = "stopped" if cell.runs_until_stopped else "interrupted"
            raise
    finally:
        wall = time.perf_counter() - started
        sim_time = context.get_time()
        if cell.recorder is not None:
            cell.recorder.drain(context, final=True)  # and what was logged before an interruption
        writer.set_metadata(**cell.metadata())
        if status == "stopped":
            writer.set_metadata(duration=sim_time)
        writer.close(status)
    return summarise(out_dir, seed, status, sim_time, wall)


def make_simulator(cell: CellDiagram) -> Simulator:
    """A simulator of ``cell`` at its initial state, paced as its I/O says; call ``Initialize()`` once
    recording is attached."""
    simulator = Simulator(cell.diagram)
    integrate_at_plant_step(simulator, cell.plant.time_step())
    cell.set_initial_state(simulator.get_mutable_context())
    simulator.set_target_realtime_rate(cell.realtime_rate)
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
    """Read a run's summary back from its black box.

    Hazards are the channels the metadata's ``hazards`` names, each with its risk
    model's initial and mishap phases: raised counts leaving the initial phase,
    handled counts returning to it, mishaps counts entering the mishap phase.
    """
    with BlackBox(out_dir / BLACKBOX) as bb:
        channels, metadata = bb.channels(), bb.metadata()
        scenario = metadata.get("scenario", {})
        summary = RunSummary(out_dir, seed, status, sim_time, wall_time, 0)
        for name, phases in (metadata.get("hazards") or {}).items():
            values = bb.series(name).values if name in channels else []
            initial, mishap = phases.get("initial"), phases.get("mishap")
            summary.hazards[name.rpartition(".")[2]] = HazardCounts(
                raised=sum(v != initial and (i == 0 or values[i - 1] == initial) for i, v in enumerate(values)),
                handled=sum(v == initial and i > 0 and values[i - 1] != initial for i, v in enumerate(values)),
                mishaps=sum(v == mishap and (i == 0 or values[i - 1] != mishap) for i, v in enumerate(values)) if mishap else 0,
            )
        behaviours = scenario.get("behaviours", {})
        robots = [n for n, e in scenario.get("entities", {}).items() if e.get("kind") == "robot"]
        summary.robots = {name: RobotFigures() for name in robots}
        for name, info in channels.items():
            if name.endswith(".cycles_completed") and info.source in behaviours:
                values = bb.series(name).values
                moved = behaviours[info.source].get("robot", "robot")  # a process moves one robot
                if moved in summary.robots:
                    summary.robots[moved].cycles_completed = int(values[-1]) if values else 0
            elif name.endswith(".safety_mode") and info.source in summary.robots:
                values = bb.series(name).values
                summary.robots[info.source].final_safety_mode = values[-1] if values else None
        if robots:
            first = summary.robots[robots[0]]
            summary.cycles_completed, summary.final_safety_mode = first.cycles_completed, first.final_safety_mode
    return summary
