"""cellsim's public Python API: every task of the command line, from a script or a notebook.

``import cellsim`` gives these names (``cellsim.__all__``); they are the public face and will stay. The
command line is a user of them: ``cellsim simulate`` calls :func:`simulate`, ``cellsim campaign``
:func:`run_campaign`, and so on, so a script and the CLI give the same black boxes and results files.

By task (docs/scripting.md has each as an example):

* a scenario: :func:`load_scenario` (a YAML file, with ``--set`` style overrides), or
  :func:`scenario_in_code` (the scenario's dataclasses built in Python; :func:`kind_config` gives a module
  kind's config class); :func:`save_scenario` writes one as YAML;
* the cell's Drake diagram: :func:`build`, with ``extend`` to add or replace systems before it is built
  (``cell.add``, ``cell.channel``, ``cell.module_input``, ``cell.builder``), and :class:`CellSystem`, the base
  of a module whose outputs are recorded channels;
* a run: :func:`simulate` (headless; with Meshcat; live, with ``io``) returns a :class:`Run`: its
  summary, its black box, its trace as arrays (:meth:`Run.series`) and as a pandas DataFrame
  (:meth:`Run.dataframe`), its verdicts (:meth:`Run.check`) and explanations (:meth:`Run.explain`);
* evidence: :func:`check` (a run folder against its conditions), :func:`check_campaign`, :func:`run_campaign`,
  :func:`falsify`, :func:`verify_cell`, each with a ``progress`` callback. (Not ``campaign`` and ``verify``:
  those are cellsim's own packages, ``cellsim.campaign`` and ``cellsim.verify``.)

Errors are exceptions with one line each: :class:`ConfigError` names the file, line and key of bad input
(a scenario built in Python: its name and the key), :class:`CheckError`, :class:`CampaignError`,
:class:`OutputExistsError` say what is wrong with a path, :class:`BlackBoxError` what is wrong with a recorded
run's black box (missing, damaged), and :class:`OverwritesInput` refuses an output named after a file it is made
from.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from cellsim.campaign import DEFAULT_SEARCH, SEARCH_METHODS  # noqa: F401 - public names (cellsim.names)
from cellsim.config.layout import Fixture, Layout, Region  # noqa: F401 - public names (cellsim.names)
from cellsim.config.typed_yaml import ConfigError
from cellsim.config.validation import Validation  # noqa: F401 - public names (cellsim.names)
from cellsim.scenario import CampaignConfig, ConfigurationPoint, Scenario, ScenarioFile, load_scenario, scenario_in_code  # noqa: F401 - public names (cellsim.names)

if TYPE_CHECKING:
    from cellsim.blackbox import BlackBox, Series
    from cellsim.campaign.falsify import FalsifyOutcome, SearchProgress
    from cellsim.campaign.runner import CampaignOutcome, Progress
    from cellsim.diagrams.cell import CellBuild, CellDiagram
    from cellsim.simulation import RunSummary
    from cellsim.validation.check import CheckedRun
    from cellsim.verify.run import Verification

from cellsim.names import PUBLIC as __all__  # noqa: E402  (listed apart: cellsim reads them without this module)

Extend = Callable[["CellBuild"], None]
"""A script's hook on the diagram being built: ``extend(cell)`` (:func:`build`)."""


_LOADED_WHEN_ASKED = {
    "CellSystem": "cellsim.systems:CellSystem",
    "CellBuild": "cellsim.diagrams.cell:CellBuild",
    "CellDiagram": "cellsim.diagrams.cell:CellDiagram",
    "CheckError": "cellsim.validation.check:CheckError",
    "BlackBoxError": "cellsim.blackbox:BlackBoxError",
    "CampaignError": "cellsim.campaign.engine:CampaignError",
    "OutputExistsError": "cellsim.simulation:OutputExistsError",
    "OverwritesInput": "cellsim.atomic:OverwritesInput",
    "Verdict": "cellsim.validation.verdict:Verdict",
    "VerifyError": "cellsim.verify.expressions:VerifyError",
    "EXPLICIT_LIMIT": "cellsim.verify.storm:EXPLICIT_LIMIT",
    "CONFIDENCE": "cellsim.validation.bound:CONFIDENCE",
    "Live": "cellsim.cell_io:Live",
    "FoxgloveFeed": "cellsim.foxglove:FoxgloveFeed",
    "open_meshcat": "cellsim.visual.serve:open_meshcat",
}
"""Public names whose modules pull Drake (or a server) in: imported when first asked for."""


def __getattr__(name: str):
    target = _LOADED_WHEN_ASKED.get(name)
    if target is None:
        raise AttributeError(f"module 'cellsim.api' has no attribute {name!r}")
    import importlib

    module, _, attribute = target.partition(":")
    return getattr(importlib.import_module(module), attribute)


# -- scenarios ----------------------------------------------------------------------------------
def kind_config(kind: str) -> type:
    """The config dataclass of module kind ``kind`` (``robot``, ``operator``, a plug-in's): what a scenario
    built in Python lists under ``entities``, ``behaviours`` or ``services``. KeyError naming the kinds there
    are for an unknown one."""
    from cellsim import registry

    if kind not in registry.kind_names():
        raise KeyError(f"no module kind '{kind}'; kinds: {', '.join(registry.kind_names())}")
    return registry.get(kind).config


def module(kind: str, **fields):
    """A module's config of kind ``kind``, from its fields as a scenario file writes them (strings for enums,
    lists for tuples, mappings for nested configs), converted and checked as a file's: ConfigError naming the
    field for a bad one. ``cellsim.module("light_barrier", center=(-1.37, 0, 1.25), size=(0.02, 0.9, 0.7))``."""
    from cellsim.config.typed_yaml import from_data, to_data

    return from_data(kind_config(kind), {"kind": kind, **to_data(fields)}, f"<{kind} module built in Python>")


def save_scenario(scenario: ScenarioFile, path: str | os.PathLike) -> Path:
    """Write ``scenario`` (resolved: overrides applied, validation inline) as YAML at ``path``, its file
    references made relative to the new file's folder; returns the path. A campaign's workers read the
    scenario from a file: save a scenario built in Python to run a campaign of it."""
    from cellsim.atomic import refuse_inputs, write_text

    path = Path(path)
    refuse_inputs(path, scenario.inputs(), "the scenario")  # (OverwritesInput: never over what it reads)
    write_text(path, scenario_yaml(scenario, path.resolve().parent))
    return path


def check_seed(seed: int, name: str = "seed") -> None:
    """ConfigError (naming ``name``: a script's or a command's own argument) unless ``seed`` is a valid seed."""
    from cellsim.scenario import check_seed as check

    check(seed, name)


def check_duration(scenario: ScenarioFile, duration: float, name: str = "duration") -> None:
    """ConfigError (naming ``name``) unless ``duration`` (s) is a run length ``scenario`` can take: positive, at
    most a day, and few enough plant steps and module updates."""
    from cellsim.scenario import check_run_length

    check_run_length(scenario, duration, name)


def scenario_yaml(scenario: ScenarioFile, relative_to: str | os.PathLike | None = None) -> str:
    """The scenario resolved (overrides applied, validation inline) as YAML text; its file references relative to
    the folder ``relative_to`` (default: the scenario's own)."""
    from cellsim.scenario import export_scenario

    return export_scenario(scenario, destination_dir=None if relative_to is None else Path(relative_to))


def compile_conditions(scenario: ScenarioFile | str | os.PathLike):
    """The scenario's safety case compiled against its cell (the diagram built and wired, every formula checked
    against the channels it records): ``conditions`` (the scenario's and the default ones), ``use_cases``.
    Raises ConfigError naming the file, line and key of a bad formula."""
    from cellsim.validation.check import scenario_safety_case

    return scenario_safety_case(_checked(scenario))


def default_conditions(scenario: ScenarioFile | str | os.PathLike) -> list[str]:
    """The names of the default conditions the scenario's modules give (``NoHarm``, ``TrueSSM``...), waived or not."""
    from cellsim.validation.defaults import default_conditions as defaults

    return list(defaults(_checked(scenario).scenario))


def _checked(scenario: ScenarioFile | str | os.PathLike) -> ScenarioFile:
    """A loaded scenario as given, its conversion and checks run again (a script may have changed it since it was
    loaded: :func:`cellsim.scenario.check_edited`)."""
    from cellsim.scenario import check_edited

    if not isinstance(scenario, ScenarioFile):
        return load_scenario(scenario)
    check_edited(scenario)
    return scenario


# -- the diagram ----------------------------------------------------------------------------------
def build(scenario: ScenarioFile | str | os.PathLike, *, seed: int | None = None, duration: float | None = None,
          extend: Extend | None = None, record: bool = False, meshcat=None) -> "CellDiagram":
    """The cell's Drake diagram, built and not yet simulated (``cell.diagram``, ``cell.plant``, ``cell.modules``,
    ``cell.channels``: every channel's output port by ``<module>.<signal>``, also exported from the diagram under
    that name).

    ``extend(cell)`` runs once the scenario's modules are built, before the recorder taps their channels: add a
    system of your own with ``cell.add(name, system)`` (a :class:`CellSystem` is recorded like any module) or
    ``cell.builder.AddSystem``, and wire it with ``cell.builder.Connect`` to ``cell.channel("range_detector.range")``
    and ``cell.module_input("robot.safety_mode_request")``. To replace a module (the risk-model engine), delete it
    from the scenario first (``del sf.scenario.behaviours["safety_controller"]``): inputs nothing drives take
    their defaults."""
    from cellsim.diagrams.cell import build_cell
    from cellsim.scenario import check_run_length, check_seed

    sf = _checked(scenario)
    if seed is not None:
        check_seed(seed, "seed argument")
    if duration is not None:
        check_run_length(sf, duration, "duration argument")
    return build_cell(sf, seed=sf.scenario.seed if seed is None else seed,
                      duration=sf.scenario.duration if duration is None else duration,
                      record=record, meshcat=meshcat, extend=extend)


# -- runs -----------------------------------------------------------------------------------------
def simulate(scenario: ScenarioFile | str | os.PathLike, out: str | os.PathLike | None = None, *,
             seed: int | None = None, duration: float | None = None, overwrite: bool = False,
             extend: Extend | None = None, meshcat=None, meshcat_wait: tuple | None = None, io=None,
             progress: Callable[[float, float], None] | None = None, check: bool = True) -> "Run":
    """Run the scenario and record its black box in ``out`` (default: ``runs/<scenario>-seed<seed>``), as
    ``cellsim simulate`` does; returns the :class:`Run`.

    ``seed``, ``duration``: the scenario's unless given. ``extend``: systems of your own (:func:`build`).
    ``meshcat``: a ``pydrake.geometry.Meshcat`` to draw the run in, at real time (``meshcat_wait``:
    ``(seconds, say)`` to wait for a browser first). ``io``: the physical side, a ``cellsim.cell_io`` choice
    (``Live`` beside a real cell, ``Emulated``, ``Replayed``); simulated by default. ``progress(t, duration)``
    after every simulated second. ``check``: judge the run against the scenario's conditions and the default
    ones (:attr:`Run.verdicts`), compiled before the folder is touched so a bad formula writes nothing.

    Raises ConfigError (bad scenario or wiring), OutputExistsError (``out`` holds a run, without ``overwrite``).
    """
    from cellsim.cell_io import SIMULATED
    from cellsim.validation.check import simulate_and_check
    from cellsim.scenario import check_run_length
    from cellsim.simulation import simulate as simulate_run

    sf = _checked(scenario)
    if seed is not None:
        check_seed(seed, "seed argument")
    if duration is not None:  # (a script's argument, named as one: not the command line's --duration)
        check_run_length(sf, duration, "duration argument")
    seed = sf.scenario.seed if seed is None else seed
    out = Path(out) if out is not None else Path("runs") / f"{sf.scenario.folder_name}-seed{seed}"
    args = dict(seed=seed, duration=duration, overwrite=overwrite, meshcat=meshcat, meshcat_wait=meshcat_wait,
                on_progress=progress, io=SIMULATED if io is None else io, extend=extend)
    if not check:
        return Run(out, simulate_run(sf, out, **args), None)
    done = simulate_and_check(sf, out, **args)
    return Run(out, done.summary, done.checked)


MOST_ROWS = 10_000_000
"""The most rows :meth:`Run.dataframe` makes at a ``period`` (ten million: a day's run every 10 ms)."""


@dataclass
class Run:
    """A recorded run: its folder, what :func:`simulate` summed up, and its verdicts.

    The black box (``out/blackbox.sqlite``) is an SQLite file any tool reads; this class reads it for you.
    """

    out: Path
    """The run's folder: ``blackbox.sqlite`` and ``scenario.yaml`` (the resolved scenario, which re-runs it)."""
    summary: "RunSummary"
    """Status, simulated and wall time, hazards' counts, figures, findings (contacts, closest approach, blind
    spots), waived default conditions."""
    checked: "CheckedRun | None" = None
    """The run judged against its conditions (None: not checked, or a scenario with none)."""

    @classmethod
    def open(cls, out: str | os.PathLike) -> "Run":
        """A run recorded earlier (by :func:`simulate` or ``cellsim simulate``): its summary read back from its
        black box and the scenario recorded beside it (its wall time is not recorded: 0)."""
        from cellsim.blackbox import BlackBox
        from cellsim.simulation import BLACKBOX, RESOLVED_SCENARIO, figures_of, summarise

        out = Path(out)
        with BlackBox(out / BLACKBOX) as bb:
            meta = bb.metadata()
        sf = load_scenario(out / RESOLVED_SCENARIO)
        summary = summarise(out, int(meta.get("seed", sf.scenario.seed)), str(meta.get("status", "unknown")),
                            float(meta.get("recorded_until", meta.get("duration", 0.0))), 0.0, figures_of(sf), sf)
        return cls(out, summary, None)

    @property
    def blackbox_path(self) -> Path:
        """The run's black box: an SQLite file (``messages``, ``channels``, ``metadata`` tables)."""
        return self.out / "blackbox.sqlite"

    def blackbox(self) -> "BlackBox":
        """The black box, open for reading (use as a context manager: ``with run.blackbox() as bb``)."""
        from cellsim.blackbox import BlackBox

        return BlackBox(self.blackbox_path)

    def channels(self) -> list[str]:
        """Every recorded channel, ``<module>.<signal>``."""
        with self.blackbox() as bb:
            return list(bb.channels())

    def series(self, *channels: str) -> dict[str, "Series"]:
        """Each channel's messages as arrays: ``series[name].times`` (s, numpy) and ``.values`` (each holds from
        its time until the next). KeyError for a channel the run did not record."""
        with self.blackbox() as bb:
            return {name: bb.series(name) for name in channels}

    def dataframe(self, channels: Sequence[str] | None = None, *, period: float | None = None):
        """The trace as a pandas DataFrame: one column per channel (default: every scalar channel), indexed by
        time (s). Without ``period``, a row at every instant any of them changed; with it, rows every ``period``
        seconds. Each value is the channel's latest message at that time (it holds until the next): what a
        reader of the channel saw. A vector channel's elements are columns ``<channel>[i]``."""
        try:
            import pandas as pd
        except ImportError:  # pragma: no cover - pandas comes with cellsim's dependencies
            raise ImportError("Run.dataframe needs pandas: pip install 'cellsim[scripting]'") from None
        if period is not None and not (isinstance(period, (int, float)) and math.isfinite(period) and period > 0):
            raise ValueError(f"period must be a positive number of seconds, got {period!r}")
        if isinstance(channels, str):
            channels = [channels]  # one channel's name: its column alone
        with self.blackbox() as bb:
            known = bb.channels()
            names = list(channels) if channels is not None else [n for n, c in known.items() if c.kind != "vector"]
            series = {name: bb.series(name) for name in names}
        columns = {}
        for name, s in series.items():
            values = list(s.values)
            if values and isinstance(values[0], list):
                for i in range(len(values[0])):
                    columns[f"{name}[{i}]"] = pd.Series([v[i] for v in values], index=s.times)
            else:
                columns[name] = pd.Series(values, index=s.times, dtype=object if _textual(values) else float)
        if period is not None:
            end = self.summary.sim_time
            if end / period > MOST_ROWS:
                raise ValueError(f"period {period:g} s would make {end / period:,.0f} rows of a {end:g} s run (at "
                                 f"most {MOST_ROWS:,}): take a longer one")
            index = [round(k * period, 9) for k in range(int(math.floor(end / period + 1e-9)) + 1)]
        else:
            index = sorted({t for c in columns.values() for t in c.index})
        frame = pd.DataFrame({name: _held(c, index) for name, c in columns.items()}, index=index)
        frame.index.name = "t"
        return frame

    @property
    def finding(self) -> bool:
        """A safety finding: a hazard reached its mishap phase, or a condition does not hold (what makes
        ``cellsim simulate`` exit 1). CheckError for a run that cannot be judged (a failed or damaged one): it is
        not taken for one without a finding."""
        if self.checked is None and self.summary.mishap is False:
            from cellsim.validation.check import NoConditions

            try:
                self.check()  # (a run opened from its folder: judged now; CheckError: it cannot be judged)
            except NoConditions:  # a scenario with no condition to judge: its mishaps alone say
                return False
        return self.summary.mishap or (self.checked is not None and not self.checked.result.all_hold)

    @property
    def verdicts(self) -> dict[str, str]:
        """Each condition's verdict on this run (``holds``, ``violated``, ``inconclusive``, ...), judged when it
        was simulated (or by :meth:`check`)."""
        if self.checked is None:
            self.check()
        return {name: v.status.value for name, v in self.checked.result.verdicts.items()}

    def check(self, scenario: ScenarioFile | None = None) -> "CheckedRun":
        """Judge the run against ``scenario``'s conditions (default: its own) and the default ones; the result
        has ``result.verdicts`` (each condition's), ``result.violations`` and ``verdict`` (the run's)."""
        self.checked = check(self.out, scenario)
        return self.checked

    def explain(self, condition: str) -> str | None:
        """Why ``condition`` is violated on this run, with the time of its first violation; None when it holds
        (or is undecided: its verdict says why). KeyError for a condition the run was not judged by."""
        if self.checked is None:
            self.check()
        verdict = self.checked.result.verdicts.get(condition)
        if verdict is None:
            raise KeyError(f"no condition '{condition}' judged this run; its conditions: "
                           f"{', '.join(self.checked.result.verdicts)}")
        if verdict.explanation is None:
            return None
        return f"violated at {verdict.violated_at:g} s: {verdict.explanation}"


def _textual(values: list) -> bool:
    return any(isinstance(v, str) for v in values)


def _held(column, index):
    """``column``'s values held from each of its times, read at ``index``'s times."""
    import pandas as pd

    return column[~column.index.duplicated(keep="last")].reindex(pd.Index(index), method="ffill")


def check(run: str | os.PathLike | Run, scenario: ScenarioFile | str | os.PathLike | None = None) -> "CheckedRun":
    """Judge a recorded run (its folder, or its black box) against ``scenario``'s conditions (default: the run's
    own scenario, recorded beside it) and the default ones, as ``cellsim check`` does.

    Returns the checked run: ``result.verdicts`` (each condition's, with ``status``, ``violated_at`` and
    ``explanation``), ``result.violations``, ``result.undecided``, ``result.use_cases``, ``result.coverage``,
    ``trace`` (the trace judged; ``trace.complete``: the run reached its end), ``case`` (the conditions).
    Raises CheckError when the run cannot be checked (no black box, a damaged one, no conditions)."""
    from cellsim.blackbox import BlackBoxError
    from cellsim.validation.check import CheckError
    from cellsim.validation.check import check as check_run
    from cellsim.validation.traces import TraceError

    if scenario is not None and not isinstance(scenario, ScenarioFile):
        scenario = load_scenario(scenario)  # (a path, as elsewhere)
    try:
        return check_run(run.out if isinstance(run, Run) else run, scenario)
    except (BlackBoxError, TraceError) as e:
        raise CheckError(str(e)) from None


def robustness(checked: "CheckedRun") -> dict:
    """Each condition's margins on a checked run: how far its thresholds (``space``, in their units) and deadlines
    (``time``, s) could move against it before its verdict changes; negative when violated
    (docs/condition-language.md, Robustness)."""
    from cellsim.logic.robustness import robustness as margins

    return {name: margins(formula, checked.trace.trace) for name, formula in checked.case.conditions.items()}


def export_trace(checked: "CheckedRun", path: str | os.PathLike) -> None:
    """Write a checked run's trace as JSON: ``{variable: [[t, value], ...]}``; refused (``OverwritesInput``) where
    ``path`` is a file the check read (the run's black box, its scenario)."""
    from cellsim.atomic import refuse_inputs
    from cellsim.validation.traces import write_trace_json

    refuse_inputs(path, checked.inputs, "the trace")
    write_trace_json(checked.trace, Path(path))


def formula_and_description(entry) -> tuple[str, str]:
    """(formula, description) of a condition or use case as a scenario writes it (bare, or with a description)."""
    from cellsim.config.validation import description_of, formula_of

    return formula_of(entry), description_of(entry)


def runs_folder(campaign: str | os.PathLike) -> Path:
    """The folder holding a campaign's (or a search's) runs, one folder each."""
    from cellsim.campaign.runner import RUNS

    return Path(campaign) / RUNS


def is_campaign(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a campaign's (or a search's) folder."""
    from cellsim.campaign.runner import PLAN

    path = Path(path)
    return path.is_dir() and (path / PLAN).is_file()


@dataclass
class CampaignCheck:
    """Every run of a campaign folder judged again (:func:`check_campaign`)."""

    folder: Path
    runs: list[dict]
    """Per run: ``run`` (its folder's name), ``status`` (completed or failed), ``violations``, ``undecided``, or
    ``error`` when it cannot be checked."""
    conditions: list[str]
    bounds: dict | None
    """Per condition and for any condition: violating runs, rate and exact upper bound, with the sampling
    distribution they hold under; None for a search's runs (:attr:`not_a_sample` says why)."""
    not_a_sample: str | None = None
    waived: dict = None
    """The default conditions the runs' scenario waives, with its reasons (none judged them)."""

    @property
    def uncheckable(self) -> list[dict]:
        return [r for r in self.runs if r["status"] == "failed"]


def check_campaign(folder: str | os.PathLike, scenario: ScenarioFile | None = None, *,
                   progress: Callable[[int, int], None] | None = None) -> CampaignCheck:
    """Judge every run of a campaign (or search) folder, as ``cellsim check FOLDER`` does, and bound the violation
    rate per condition; ``progress(done, total)`` after each run. Runs that cannot be checked are listed, never
    dropped silently. Raises CheckError for a folder with no runs."""
    import json

    from cellsim.campaign.falsify import NOT_A_SAMPLE, read_search
    from cellsim.campaign.runner import PLAN, RESULT, RESULTS, RUNS, sampled_bounds
    from cellsim.validation.bound import campaign_bounds
    from cellsim.validation.check import CheckError

    folder = Path(folder)
    folders = sorted(p for p in (folder / RUNS).glob("*") if p.is_dir())
    if not folders:
        raise CheckError(f"{folder}: a campaign folder with no runs yet")
    runs, conditions, waived = [], {}, {}
    for done, path in enumerate(folders, start=1):
        if not (path / RESULT).is_file():  # stopped before it ended (Ctrl-C): the campaign runs it again
            runs.append({"run": path.name, "status": "unfinished"})
            if progress is not None:
                progress(done, len(folders))
            continue
        recorded = _recorded_failure(path / RESULT)
        if recorded is not None:  # the campaign counted it nowhere: neither does its check
            runs.append({"run": path.name, "status": "failed", "error": recorded})
            if progress is not None:
                progress(done, len(folders))
            continue
        try:
            judged = check(path, scenario)
        except (CheckError, ConfigError) as e:  # a run that was damaged (its scenario too)
            runs.append({"run": path.name, "status": "failed", "error": str(e)})
        else:
            result = judged.result
            waived.update(judged.case.validation.waive)
            conditions.update(dict.fromkeys(result.verdicts))
            runs.append({"run": path.name, "status": "completed", "violations": result.violations,
                         "undecided": result.undecided})
        if progress is not None:
            progress(done, len(folders))
    if read_search(folder) is not None or any(_chosen_by_search(path) for path in folders):
        return CampaignCheck(folder, runs, list(conditions), None, NOT_A_SAMPLE, waived)  # a search chose them: no bound
    try:
        stored = json.loads((folder / RESULTS).read_text())["bounds"]
        distribution = stored.get("distribution")
        if distribution is None:  # (a folder from before the distribution was kept apart: its statement, as it was)
            sampling = stored.get("drawn_from", stored["sampling"])  # (before the failed runs' clause: said again)
            if not isinstance(sampling, str):
                raise TypeError(sampling)
            return CampaignCheck(folder, runs, list(conditions), campaign_bounds(runs, list(conditions), sampling),
                                 waived=waived)
        if not isinstance(distribution, str):
            raise TypeError(distribution)
    except (OSError, ValueError, KeyError, TypeError):  # a bound is nothing without the distribution it holds under
        return CampaignCheck(folder, runs, list(conditions), None,
                             f"{folder / RESULTS} is missing or records no sampling distribution: what the runs were "
                             "drawn from is not known, so no violation rate or bound follows from them", waived)
    # how the number of runs was decided, said of the runs counted now (campaign.json keeps each command's sizing: an
    # extension stopped before it wrote its results leaves them stale)
    try:
        sizing = json.loads((folder / PLAN).read_text()).get("sizing") or []
    except (OSError, ValueError, AttributeError):
        sizing = []
    return CampaignCheck(folder, runs, list(conditions), sampled_bounds(runs, list(conditions), distribution, sizing),
                         waived=waived)


def _recorded_failure(result_file: Path) -> str | None:
    """Why the campaign recorded a run as not completed (a simulation that failed, a check that did), or None for a
    run it completed: such a run is in no bound of the campaign, and a check of the folder keeps it out too."""
    import json

    try:
        result = json.loads(result_file.read_text())
        status = result.get("status")
    except (OSError, ValueError, AttributeError) as e:
        return f"its {result_file.name} cannot be read ({e})"
    if status == "completed":
        return None
    error = result.get("error")
    return f"the campaign recorded it {status}" + (f": {error}" if error else "")


def _chosen_by_search(run: Path) -> bool:
    """Whether a run's own result records a falsification search's choice of it."""
    import json

    from cellsim.campaign.runner import RESULT

    try:
        return isinstance(json.loads((run / RESULT).read_text()).get("search"), dict)
    except (OSError, ValueError, AttributeError):
        return False


# -- evidence -------------------------------------------------------------------------------------
def _scenario_file(scenario: ScenarioFile | str | os.PathLike) -> tuple[str, tuple[str, ...]]:
    """(the scenario's file, its overrides): what a campaign's workers load again. A scenario built in Python, or
    changed in code since it was loaded, is refused (ConfigError): its runs would read the file, not it."""
    if isinstance(scenario, ScenarioFile):
        if scenario.built_in_code:
            raise ConfigError(scenario.source, None, "", "a campaign's runs read their scenario from a file: save it "
                              "first (cellsim.save_scenario) and give that file")
        _refuse_edited(scenario, "a campaign's runs read their scenario from its file")
        return str(Path(scenario.source).resolve()), tuple(scenario.overrides)
    return str(Path(scenario).resolve()), ()


def _refuse_edited(scenario: ScenarioFile, why: str) -> None:
    """ConfigError when ``scenario`` differs from what its file and overrides load as (a script changed it in place):
    ``why`` says which work reads the file instead."""
    from cellsim.config.typed_yaml import to_data

    if to_data(scenario.scenario) != to_data(load_scenario(scenario.source, list(scenario.overrides)).scenario):
        raise ConfigError(scenario.source, None, "", f"the scenario was changed in code since it was loaded, and {why}: "
                          "save it first (cellsim.save_scenario) and give that file")


COUNT_LIMITS = {"runs": 100_000, "budget": 100_000, "jobs": 256, "batch": 10_000}
"""The most a campaign's or a search's ``runs``, ``budget``, ``jobs`` and ``batch`` may be (each at least 1)."""


def _check_run_arguments(sf: ScenarioFile, seed, duration, **counts) -> None:
    """ConfigError naming the argument unless each of ``counts`` is a whole number in [1, its limit], the seed a seed
    and the duration (when given) a run length the scenario can take: before any folder is touched."""
    import numbers

    for name, value in counts.items():
        most = COUNT_LIMITS[name]
        if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Integral)
                                  or not 1 <= value <= most):
            raise ConfigError(name, None, "", f"must be a whole number in [1, {most:,}], got {value!r}")
    check_seed(seed)
    if duration is not None:
        check_duration(sf, duration, "duration (the argument)")


def run_campaign(scenario: ScenarioFile | str | os.PathLike, out: str | os.PathLike, *, runs: int | None = None,
             seed: int = 0, duration: float | None = None, jobs: int = 1, scheduler: str | None = None,
             restart: bool = False, until_bound: float | None = None,
             progress: Callable[["Progress"], None] | None = None) -> "CampaignOutcome":
    """Run (or resume) a campaign into ``out``, as ``cellsim campaign`` does: ``results.json``, ``report.html``,
    a folder per run. ``runs``: the scenario's ``campaign.runs`` unless given. ``jobs`` local processes, or a Dask
    ``scheduler`` address. ``progress(p)`` after every run (``p.done``, ``p.total``, ``p.violating_runs``,
    ``p.failed``, ``p.coverage``). Returns the outcome (``results``: what results.json holds)."""
    from cellsim.campaign.runner import CampaignPlan
    from cellsim.campaign.runner import run_campaign as run

    path, overrides = _scenario_file(scenario)
    sf = scenario if isinstance(scenario, ScenarioFile) else load_scenario(path)
    if until_bound is not None:
        if not (isinstance(until_bound, (int, float)) and 0.0 < until_bound < 1.0):
            raise ConfigError("until_bound", None, "", f"must be a probability in (0, 1), got {until_bound!r}")
        needed = runs_needed(until_bound)
        if runs is not None and runs != needed:
            raise ConfigError("until_bound", None, "", f"{until_bound:g} takes {needed:,} runs without a violation, "
                              f"not the {runs:,} given: give runs=None (or {needed:,})")
        runs = needed
    _check_run_arguments(sf, seed, duration, runs=runs, jobs=jobs)
    plan = CampaignPlan(path, overrides, seed, sf.scenario.campaign.runs if runs is None else runs, duration,
                        until_bound=until_bound)
    return run(plan, out, jobs=jobs, on_progress=progress, restart=restart, scheduler=scheduler)


def falsify(scenario: ScenarioFile | str | os.PathLike, out: str | os.PathLike, *, budget: int,
            method: str = DEFAULT_SEARCH, conditions: Sequence[str] = (), seed: int = 0, duration: float | None = None,
            jobs: int = 1, batch: int | None = None, scheduler: str | None = None, overwrite: bool = False,
            progress: Callable[["SearchProgress"], None] | None = None) -> "FalsifyOutcome":
    """Search the scenario's configuration points for runs that violate ``conditions`` (default: all), as
    ``cellsim falsify`` does, spending at most ``budget`` runs: ``method`` ``qd`` (the command's default too),
    ``cmaes`` or ``random``. ``progress(p)`` after every batch (``p.done``, ``p.budget``, ``p.best``,
    ``p.violating``). A search's runs are no random sample: its results carry no bound."""
    from cellsim.campaign.falsify import FalsifyPlan, run_falsify

    path, overrides = _scenario_file(scenario)
    if isinstance(conditions, str):
        raise ConfigError("conditions", None, "", f"is a list of condition names, got the string {conditions!r}")
    if method not in SEARCH_METHODS:
        raise ConfigError("method", None, "", f"{method!r} is no search method; methods: {', '.join(SEARCH_METHODS)}")
    _check_run_arguments(scenario if isinstance(scenario, ScenarioFile) else load_scenario(path), seed, duration,
                         budget=budget, jobs=jobs, batch=batch)
    plan = FalsifyPlan(path, overrides, seed, budget, method, duration, tuple(conditions))
    return run_falsify(plan, out, jobs=jobs, on_progress=progress, overwrite=overwrite, batch=batch,
                       scheduler=scheduler)


def runs_needed(probability: float, confidence: float | None = None) -> int:
    """How many runs with no violation bound the violation rate below ``probability`` at ``confidence`` (default:
    the campaigns' 95 %), by the exact (Clopper-Pearson) bound a campaign reports."""
    from cellsim.validation.bound import CONFIDENCE
    from cellsim.validation.bound import runs_needed as needed

    return needed(probability, CONFIDENCE if confidence is None else confidence)


def verify_cell(scenario: ScenarioFile | str | os.PathLike, *, export: str | os.PathLike | None = None,
                timed: bool = False, replay_in: str | os.PathLike | None = None, refine: int | None = None,
                progress: Callable[[str], None] | None = None, only: Sequence[str] = ()) -> "Verification":
    """Model-check the scenario's abstraction with Storm, as ``cellsim verify`` does: ``result.results`` holds
    each property's value, whether it holds in the abstraction, and a witness path where it does not;
    ``result.endings()`` each property's final verdict (holds; violated: a witness the twin confirms; undecided,
    with why) and ``result.exit_code`` the CLI's; ``result.model.cell.assumptions`` the abstraction's assumptions.
    ``export``: also write the PRISM model to that file (and its properties beside it, with ``.props``). ``replay_in``: refine the abstraction where a
    witness does what a module cannot and check again, at most ``refine`` times (default 3;
    ``result.refinements`` lists them), and replay every other witness in the twin, writing its runs in that folder
    (``result.replays[name]``). ``progress(stage)`` as each stage starts. ``only``: name patterns (shell-style,
    ``"HS:*"``) of the properties to check, none: every one (the others are not modelled at all;
    ``result.model.unasked`` names them). Raises VerifyError for a scenario the abstraction cannot take, or a
    pattern that names none of its properties."""
    from cellsim.verify.refine import DEFAULT_BUDGET, verify_with_twin
    from cellsim.verify.run import export_paths, verify

    sf, export = _checked(scenario), None if export is None else Path(export)
    only = (only,) if isinstance(only, str) else tuple(only)  # one name, or several
    if export is not None:
        export_paths(export, sf)  # refused before anything is built: over an input, or the model over its props
    if replay_in is None:
        return verify(sf, export=export, timed=timed, on_stage=progress, only=only)
    if sf.built_in_code:
        raise ConfigError(sf.source, None, "", "a witness is replayed as a scenario over the verified one's file: "
                          "save it first (cellsim.save_scenario) and give that file")
    _refuse_edited(sf, "a witness is replayed as a scenario over its file")
    return verify_with_twin(sf, Path(replay_in), budget=DEFAULT_BUDGET if refine is None else refine, timed=timed,
                            export=export, on_stage=progress, only=only)


def __dir__() -> list[str]:
    return sorted(__all__)

