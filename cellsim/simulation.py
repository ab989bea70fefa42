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
from typing import Any, Callable

from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

from cellsim import registry
from cellsim.atomic import LOCK, FolderBusy, folder_lock
from cellsim.config.typed_yaml import to_data
from cellsim.hazards import HazardCounts, HazardPhases
from cellsim.kind import Figure, Finding
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
class RunSummary:
    out_dir: Path
    seed: int
    status: str
    sim_time: float
    wall_time: float
    hazards: dict[str, HazardCounts] = field(default_factory=dict)
    """Each hazard's counts, by its channel (``safety_controller.HRW``)."""
    figures: list[tuple[Figure, object]] = field(default_factory=list)
    """The figures the modules' kinds give (:meth:`cellsim.kind.ModuleKind.figures`), each with its value
    (None: its channel has no message), in the scenario's order."""
    findings: list[Finding] = field(default_factory=list)
    """What the modules' kinds find in the black box (:meth:`cellsim.kind.ModuleKind.findings`): each contact with a
    person, the closest approach, each blind spot of a sensor."""
    waived: dict[str, str] = field(default_factory=dict)
    """The default conditions the scenario waives, with its reasons."""

    @property
    def harmed(self) -> bool:
        """A contact above its region's limit (severity above 1)."""
        return any(f.what == "contact" and f.data.get("severity", 0.0) > 1.0 for f in self.findings)

    @property
    def worst_severity(self) -> float:
        """The worst contact's severity in the run (0: no contact)."""
        return max((f.data.get("severity", 0.0) for f in self.findings if f.what == "contact"), default=0.0)

    @property
    def real_time_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")

    @property
    def mishap(self) -> bool:
        return any(h.mishaps for h in self.hazards.values())

    def figures_json(self) -> dict[str, dict[str, object]]:
        """``{subject: {key: value}}``: what a campaign's results keep of the figures."""
        out: dict[str, dict[str, object]] = {}
        for figure, value in self.figures:
            out.setdefault(figure.subject, {})[figure.key] = value
        return out


class RunFolder:
    """An exclusive claim on a run's output folder, held while the run is written.

    The claim is :func:`cellsim.atomic.folder_lock`: a second process that asks
    for the same folder is refused at once, and the lock goes with its holder
    however that ends, SIGKILL included. The folder must be new, empty, or hold a
    run (replaced only with ``overwrite``); the current folder is refused, so a
    run never mixes its files with the user's.

    A run that replaces another is written beside it (``writing``, a hidden folder
    in the same parent) and takes its place only at :meth:`commit`, once written:
    until then the old run is whole, and a run that fails or is interrupted is
    removed, leaving the old one as it was.
    """

    def __init__(self, out_dir: str | os.PathLike, overwrite: bool = False):
        self.path = Path(out_dir)
        self.overwrite = overwrite
        self.writing = self.path
        """The folder to write the run into: ``path``, or beside it while an old run is there."""
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
                    raise OutputExistsError(f"{out} already holds a run ({BLACKBOX}); choose another --out or pass "
                                            "--overwrite (overwrite=True in a script)")
                self.writing = self._beside(Path(os.path.realpath(out)), "overwriting")
                shutil.rmtree(self.writing, ignore_errors=True)  # (one a killed process left: ours, we hold the lock)
                self.writing.mkdir()
        except BaseException:
            self._lock.close()
            raise
        return self

    @staticmethod
    def _beside(out: Path, what: str) -> Path:
        return out.parent / f".{out.name}.{what}"

    def commit(self) -> None:
        """Put the run written into ``writing`` in the old run's place (nothing to do for a new folder): the folder
        ``path`` names (a link's target, the link kept), with the files beside the old run that no run wrote (the
        user's: an export, notes) moved into it."""
        if self.writing == self.path:
            return
        real = Path(os.path.realpath(self.path))
        for item in real.iterdir():
            if item.name not in (BLACKBOX, RESOLVED_SCENARIO, LOCK, INPUTS) and not item.name.startswith(BLACKBOX):
                os.replace(item, self.writing / item.name)
        replaced = self._beside(real, "replaced")
        shutil.rmtree(replaced, ignore_errors=True)
        os.replace(real, replaced)
        os.replace(self.writing, real)
        self.writing = self.path
        shutil.rmtree(replaced, ignore_errors=True)

    def __exit__(self, *exc) -> None:
        if self.writing != self.path:  # not committed: the old run stays
            shutil.rmtree(self.writing, ignore_errors=True)
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
    before_run: Callable[[Any], None] | None = None,
    extend: Callable[[Any], None] | None = None,
) -> RunSummary:
    """Run ``sf`` with the I/O ``io`` (``cellsim.cell_io``: simulated by default), recording to ``out_dir``.

    One loop whatever the I/O: the builder decides what the physical side is and
    whether the run is paced to the wall clock; the network's work happens inside
    the diagram. A live or emulated run goes until ``duration`` or until it is
    stopped (Ctrl-C, SIGTERM): its record is then complete, ending there.
    ``meshcat_wait``: ``(seconds, say)`` to wait for a browser before simulated time runs.

    The black box's ``provenance`` metadata is :func:`cellsim.provenance.provenance`
    of the run's inputs, updated with ``provenance`` (a campaign names itself there).

    ``before_run(cell)`` is called with the built cell before the run folder is touched: what it
    refuses (``cellsim.validation.check.simulate_and_check`` compiles the safety conditions against
    the cell's channels there) leaves nothing written.

    ``extend(cell)``: a script's own systems added to the diagram (:func:`cellsim.diagrams.cell.build_cell`).
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
    # caller's before_run its own inputs against the cell.
    cell = build_cell(sf, seed=seed, duration=duration, io=io, meshcat=meshcat, meshcat_wait=meshcat_wait,
                      extend=extend)
    try:
        if before_run is not None:
            before_run(cell)
        simulator = make_simulator(cell)
        inputs.check_unchanged()  # what was built is what was read, copied and hashed
        with RunFolder(out_dir, overwrite) as folder:
            try:
                summary = _record(cell, simulator, folder.writing, seed, duration, on_progress, inputs, record,
                                  _name_of(extend))
            except BaseException:
                if cell.runs_until_stopped:  # a live run's record, stopped or failed, is what happened: kept
                    folder.commit()
                raise
            folder.commit()
            summary.out_dir = out_dir
    finally:
        cell.close()
    return summary


def _name_of(extend) -> str | None:
    """How a run names the script's function that extended its diagram (None: not extended)."""
    if extend is None:
        return None
    return f"{getattr(extend, '__module__', None) or '?'}.{getattr(extend, '__qualname__', None) or repr(extend)}"


def _record(cell, simulator, out_dir: Path, seed: int, duration: float, on_progress, inputs, record,
            extended_by: str | None = None) -> RunSummary:
    """Write the resolved scenario and its input files, then simulate while recording the black box."""
    sf = cell.sf
    sc = sf.scenario
    write_run_scenario(sf, inputs, out_dir, RESOLVED_SCENARIO, seed, duration, extended_by)

    writer = None
    status = "failed"
    started = time.perf_counter()
    context = simulator.get_mutable_context()
    sim_time = 0.0
    try:
        writer = BlackBoxWriter(out_dir / BLACKBOX)  # (in the try: stopped as it opens, it is closed all the same)
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
            **({"extended_by": extended_by} if extended_by else {}),
        )
        try:
            simulator.Initialize()
            cell.start(context)  # may wait for a browser, or for the physical cell
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
    except KeyboardInterrupt:  # before simulated time began (the record being opened): interrupted all the same
        if status == "failed":
            status = "interrupted"
        raise
    finally:
        wall = time.perf_counter() - started
        sim_time = context.get_time()
        if writer is None:  # stopped as the black box was being opened: it holds nothing, and goes
            for leftover in (out_dir / BLACKBOX, *(out_dir / f"{BLACKBOX}{end}" for end in ("-wal", "-shm", "-journal"))):
                leftover.unlink(missing_ok=True)
        else:
            if cell.recorder is not None:
                cell.recorder.drain(context, final=True)  # and what was logged before an interruption
            writer.set_metadata(**cell.metadata())
            if status == "stopped":
                writer.set_metadata(duration=sim_time)
            writer.close(status)
    return summarise(out_dir, seed, status, sim_time, wall, figures_of(sf), sf)


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


def figures_of(sf: ScenarioFile) -> list[Figure]:
    """The figures of a run of ``sf``, as its modules' kinds give them, in the scenario's order."""
    sc = sf.scenario
    return [figure for section in registry.SECTIONS for name, cfg in getattr(sc, section).items()
            for figure in registry.kind_of(cfg).figures(name, cfg)]


def summarise(out_dir: Path, seed: int, status: str, sim_time: float, wall_time: float,
              figures: list[Figure] = (), sf: ScenarioFile | None = None) -> RunSummary:
    """Read a run's summary back from its black box.

    Hazards are the channels the metadata's ``hazards`` names, each counted by its risk
    model's phases (:class:`cellsim.hazards.HazardPhases`); each of ``figures`` is its
    channel's last value; with the scenario ``sf``, its modules' kinds' findings (contacts, the
    closest approach, blind spots) and its waived default conditions.
    """
    with BlackBox(out_dir / BLACKBOX) as bb:
        channels, metadata = bb.channels(), bb.metadata()
        summary = RunSummary(out_dir, seed, status, sim_time, wall_time)
        hazards = metadata.get("hazards") or {}
        if not isinstance(hazards, dict):
            raise bb.corrupt(f"its metadata's hazards are {type(hazards).__name__}, not channels and their phases")
        for name, phases in hazards.items():
            values = bb.series(name).values if name in channels else []
            try:
                summary.hazards[name] = HazardPhases.of(phases).counts(values)
            except (TypeError, KeyError, ValueError, AttributeError) as e:
                raise bb.corrupt(f"its metadata's phases of hazard '{name}' are not a risk model's ({e})") from None
        for figure in figures:
            values = bb.series(figure.channel).values if figure.channel in channels else []
            last = values[-1] if values else None
            summary.figures.append((figure, int(last) if isinstance(last, float) and last.is_integer() else last))
        if sf is not None:
            summary.findings = findings_of(sf, bb)
            summary.waived = dict(sf.scenario.validation.waive)
    return summary


def findings_of(sf: ScenarioFile, blackbox: BlackBox) -> list[Finding]:
    """What each module's kind finds in a run's black box, in the scenario's order; then, of a live twin's run,
    the entities it reacted to slower than the scenario assumes."""
    from cellsim.live.reaction import reaction_findings

    sc = sf.scenario
    return [finding for section in registry.SECTIONS for name, cfg in getattr(sc, section).items()
            for finding in registry.kind_of(cfg).findings(name, cfg, blackbox)] + reaction_findings(blackbox.metadata())
