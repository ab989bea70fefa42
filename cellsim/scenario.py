"""The scenario digital twin: one YAML file, loaded into typed dataclasses.

A scenario names the cell's layout (fixtures and regions), its entities with
their kind, parameters and twin mode, its behaviours (process controller, safety
controller, analyses), its services (recorder) and its configuration points.
All lengths are metres, times seconds, speeds m/s, angles radians unless a field
name says ``_deg``.

``load_scenario`` reads a file, applies ``--set`` overrides and checks
everything that can be checked without building the diagram; every problem is a
``ConfigError`` naming file, line and key. ``export_scenario`` writes the fully
resolved scenario, which loads back to an equal one.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Annotated

from cellsim.config.typed_yaml import (
    ConfigError,
    FieldError,
    Loaded,
    Range,
    range_of,
    type_at,
    apply_overrides,
    dump_yaml,
    from_data,
    load_file,
    to_data,
)
from cellsim.config.sampling import Sampler
from cellsim import registry
from cellsim.registry import BehaviourModule, EntityModule, KindError, ServiceModule, kind_of
from cellsim.config.validation import Validation
from cellsim.config.layout import Layout
from cellsim.config.units import MAX_DURATION, MAX_MODULE_UPDATES, MAX_PLANT_STEPS, SEEDS, PositiveSeconds

@dataclass
class ConfigurationPoint:
    """A named, documented value of the scenario that runs may vary."""

    paths: list[str]
    """The dotted keys it sets (a module's name stands for its section: ``operator.waypoints.cell.wait``)."""
    description: str = ""
    """What it is, for people."""


@dataclass
class CampaignConfig:
    """Defaults of ``cellsim campaign``: how many runs, and how each configuration point is drawn."""

    runs: Annotated[int, Range(1, 100_000)] = 100
    """Runs of a campaign when ``--runs`` does not say."""
    samplers: dict[str, Sampler] = field(default_factory=dict)
    """Configuration point name -> sampler (``uniform``, ``choice`` or ``simplex``)."""


KEY_SPECIAL = ("/", "*", "$", "?", "#")
"""What a scenario's name may not hold: Zenoh's separator and wildcards ('x*' would be no key at all; '*' would read
every cell's physical samples), docs/live.md."""


@dataclass
class Scenario:
    name: str
    """The scenario's name (run and campaign folders are named after it, and so are the live twin's keys: none of
    / * $ ? #)."""
    layout: Layout
    """The cell's fixtures and named volumes."""
    entities: dict[str, EntityModule]
    """Module name -> its config; ``kind`` names its module kind (``cellsim modules`` lists them)."""
    behaviours: dict[str, BehaviourModule] = field(default_factory=dict)
    """Module name -> its config: process and safety controllers, analyses."""
    services: dict[str, ServiceModule] = field(default_factory=dict)
    """Module name -> its config: the recorder."""
    configuration_points: dict[str, ConfigurationPoint] = field(default_factory=dict)
    """Named, documented values of the scenario that a campaign varies."""
    validation: Validation = field(default_factory=Validation)
    """Safety conditions, use cases and coverage criteria, inline or in a file it names."""
    campaign: CampaignConfig = field(default_factory=CampaignConfig)
    """Defaults of ``cellsim campaign``."""
    description: str = ""
    """What the scenario is, for people."""
    duration: PositiveSeconds = 30.0
    """Simulated seconds of a run (also at most 5e7 plant steps and 1e8 module updates)."""
    seed: Annotated[int, SEEDS] = 0
    """The run's random seed: a run is a pure function of the scenario and the seed."""
    time_step: Annotated[float, Range(0.0001, 0.01, unit="s")] = 0.002
    """The robot plant's discrete step (s): 2 ms, the 500 Hz of a UR controller's joint loop."""

    def __post_init__(self):
        if not self.name.strip() or any(c in self.name for c in KEY_SPECIAL):
            raise FieldError("name", f"{self.name!r}: a scenario's name is its cell's name in the live twin's keys "
                             f"(cellsim/<name>/...): not empty, and none of {' '.join(KEY_SPECIAL)}")
        seen: dict[str, str] = {}
        for section in ("entities", "behaviours", "services"):
            for name in getattr(self, section):
                if name in seen:
                    raise FieldError(f"{section}.{name}", f"module name '{name}' is already used in {seen[name]}")
                if not name.isidentifier():
                    raise FieldError(f"{section}.{name}", "module names must be identifiers (letters, digits, _)")
                seen[name] = section

    @property
    def folder_name(self) -> str:
        """The name as one folder's name (the default run and campaign folders are named after it): letters,
        digits, '-', '_' and '.' kept, anything else (a '/', a space) made '_', no leading dot: a name like
        '../x' never names a folder outside ``runs/``."""
        safe = re.sub(r"[^A-Za-z0-9._-]", "_", self.name).lstrip(".")
        return safe or "scenario"

    def modules_of_kind(self, kind: str) -> dict[str, object]:
        """Every module of kind ``kind``, by name, whatever its section."""
        found = {}
        for section in (self.entities, self.behaviours, self.services):
            found.update({n: c for n, c in section.items() if c.kind == kind})
        return found


# -- files ----------------------------------------------------------------------
@dataclass
class ScenarioFile:
    """A loaded scenario with where it came from, for resolving paths and naming lines."""

    loaded: Loaded[Scenario]
    overrides: list[str] = field(default_factory=list)
    validation_file: Loaded[Validation] | None = None
    """Where ``validation`` was read from, when the scenario names a file for it."""
    built_in_code: bool = False
    """Built in Python (:func:`scenario_in_code`), not read from a file: ``source`` names no file, and the run's
    provenance records the scenario's text as YAML."""

    @property
    def scenario(self) -> Scenario:
        """The scenario's dataclasses, overrides applied: change them in a script before building or simulating."""
        return self.loaded.value

    @property
    def source(self) -> str:
        """The scenario's file (for a scenario built in Python, a name in ``base_dir`` that is no file)."""
        return self.loaded.source

    @property
    def base_dir(self) -> Path:
        """The folder the scenario's relative file references are read from."""
        return Path(self.loaded.source).resolve().parent

    def error(self, key: str, problem: str) -> ConfigError:
        """A ConfigError at ``key`` (dotted path), naming the file (the scenario or a base) and line; or ``--set``,
        where an override gave the value."""
        if self._overridden(key):
            return ConfigError("--set", None, key, problem)
        return ConfigError(*self.loaded.where(key), key, problem)

    def _overridden(self, key: str) -> bool:
        """Whether an override (``--set``) gave ``key``'s value, or that of a mapping holding it."""
        resolve = _shortcut(self.scenario)
        for assignment in self.overrides:
            parts = [p.strip() for p in assignment.partition("=")[0].split(".")]
            try:
                full = ".".join(str(p) for p in resolve(parts))
            except Exception:  # noqa: BLE001 - an override that names nothing was refused when it was applied
                continue
            if key == full or key.startswith(full + "."):
                return True
        return False

    def locate(self, key: str) -> tuple[str, int | None, str]:
        """(file, line, key in that file) where the dotted ``key`` is written, following ``validation.file``."""
        written_inline = any(k == key or k.startswith(key + ".") for k in self.loaded.lines)
        if self.validation_file is not None and key.startswith("validation.") and not written_inline:
            key = key.removeprefix("validation.")
            return self.validation_file.source, self.validation_file.line_of(key), key
        return (*self.loaded.where(key), key)

    def file_dir(self, key: str) -> Path:
        """The folder of the file in which ``key`` was written (the scenario's or a base's)."""
        return Path(self.loaded.where(key)[0]).resolve().parent

    @property
    def files(self) -> list[str]:
        """Every file this scenario was read from: itself, its bases, its validation file."""
        files = list(self.loaded.files or [self.source])
        if self.validation_file is not None:
            files.append(self.validation_file.source)
        return files

    def inputs(self) -> list[str]:
        """Every file a command reads for this scenario: :attr:`files` and each module's file references (a risk
        model, a robot model, a limits table), so that no output is written over one of them."""
        found = list(self.files)
        for section in ("entities", "behaviours", "services"):
            for module, cfg in getattr(self.scenario, section).items():
                for name in kind_of(cfg).files:
                    if getattr(cfg, name, None) is not None:
                        found.append(str(self.file_dir(f"{section}.{module}.{name}") / getattr(cfg, name)))
        return found

    def resolve_path(self, key: str, relative: str) -> Path:
        """An existing file named at ``key``, relative to the file that names it."""
        path = Path(relative)
        if not path.is_absolute():
            path = self.file_dir(key) / path
        if path.is_dir():
            raise self.error(key, f"{relative} is a folder, not a file (looked for {path})")
        if not path.is_file():
            raise self.error(key, f"file not found: {relative} (looked for {path})")
        return path.resolve()


def _shortcut(scenario: Scenario):
    """``--set operator.wait=...`` means ``entities.operator.wait``: module names are roots."""

    def resolve(parts: list[str]) -> list[str]:
        if parts and not hasattr(scenario, parts[0]):
            for section in ("entities", "behaviours", "services"):
                if parts[0] in getattr(scenario, section):
                    return [section, *parts]
        return parts

    return resolve


def load_scenario(path: str | os.PathLike, overrides: list[str] | tuple[str, ...] = ()) -> ScenarioFile:
    """Load, override and check a scenario; raises ConfigError on any bad input."""
    if isinstance(overrides, str):
        raise ConfigError("--set", None, "", f"the overrides are a list of PATH=VALUE strings, got the string "
                          f"{overrides!r} (write [{overrides!r}])")
    loaded = load_file(Scenario, path, base_key="base")
    _add_default_modules(loaded.value)  # before the overrides: ``--set harm.cutoff=...`` sets the default's
    apply_overrides(loaded, list(overrides), resolve=_shortcut(loaded.value))
    sf = ScenarioFile(loaded, list(overrides))
    _load_validation_file(sf)
    check_scenario(sf)
    return sf


def check_edited(sf: ScenarioFile) -> None:
    """The scenario as a script may have changed it since it was loaded (``sf.scenario...`` set in place) put through
    the conversion and checks a file's goes through: a wrong type or a value out of range is a ConfigError naming
    the key (its source: the scenario, as changed in code), never an error deep inside the run."""
    from_data(Scenario, to_data(sf.scenario), f"{sf.source} (as changed in code)")
    check_scenario(sf)


def scenario_in_code(scenario: Scenario, base_dir: str | os.PathLike = ".") -> ScenarioFile:
    """A scenario built in Python, checked as a file's would be; raises ConfigError naming the key.

    ``scenario``'s modules may be their kinds' config dataclasses or plain mappings with a ``kind``: the
    scenario goes through the same conversion and checks as a file's. Files it names (a robot model, a risk
    model, a validation file) are relative to ``base_dir``. Errors name ``<name> (built in Python)`` and the key.
    """
    base = Path(base_dir).resolve()
    source = str(base / f"<{scenario.name} (built in Python)>")
    value = from_data(Scenario, to_data(scenario), source)
    loaded = Loaded(value=value, source=source, lines={})
    _add_default_modules(value)
    sf = ScenarioFile(loaded, [], built_in_code=True)
    _load_validation_file(sf)
    check_scenario(sf)
    return sf


def _add_default_modules(sc: Scenario) -> None:
    """Every kind's ``default_module`` (the harm service) where the scenario lists none of that kind."""
    from cellsim import registry

    for name in registry.kind_names():
        try:
            kind = registry.get(name)
        except KindError:
            continue  # a broken plug-in is reported where a scenario uses it
        module = kind.default_module
        if module is None or sc.modules_of_kind(kind.name):
            continue
        if any(module in getattr(sc, section) for section in ("entities", "behaviours", "services")):
            continue  # the name is the scenario's own module: nothing is added behind its back
        getattr(sc, kind.section)[module] = kind.config(kind=kind.name)


def _load_validation_file(sf: ScenarioFile) -> None:
    """Read the validation section from the file it names, adding the entries written inline.

    Inline entries extend the file's (a misuse scenario adds its second person's
    variables to the welding cell's conditions) and replace entries of the same
    name. The scenario then holds the merged section inline.
    """
    inline = sf.scenario.validation
    if not inline.file:
        return
    path = sf.resolve_path("validation.file", inline.file)
    sf.validation_file = load_file(Validation, path)
    merged = sf.validation_file.value
    if merged.file:
        raise ConfigError(str(path), sf.validation_file.line_of("file"), "file", "a validation file cannot name another")
    for f in fields(Validation):
        if f.name != "file":
            getattr(merged, f.name).update(getattr(inline, f.name))
    sf.scenario.validation = merged


def check_scenario(sf: ScenarioFile) -> None:
    """Cross-references a dataclass cannot check alone: each kind's own checks, samplers, points."""
    sc = sf.scenario
    for section in ("entities", "behaviours", "services"):
        for name, cfg in getattr(sc, section).items():
            kind = _kind(sf, f"{section}.{name}", cfg)
            with registry.plugin_failures(kind, sf, f"{section}.{name}", "check"):
                kind.check(sf, name, cfg)
            period = getattr(cfg, "period", None)
            if isinstance(period, float) and not _whole_steps(period, sc.time_step):
                raise sf.error(
                    f"{section}.{name}.period",
                    f"{period:g} s is not a whole number of plant steps (time_step {sc.time_step:g} s): "
                    "every event of the cell falls on a plant step",
                )
    check_run_length(sf, sc.duration, "duration")
    for name in sc.campaign.samplers:
        if name not in sc.configuration_points:
            known = ", ".join(sc.configuration_points) or "none"
            raise sf.error(f"campaign.samplers.{name}", f"no configuration point named '{name}' (known: {known})")
    for name, point in sc.configuration_points.items():
        for i, dotted in enumerate(point.paths):
            try:
                value_at(sc, dotted)
            except KeyError:
                raise sf.error(f"configuration_points.{name}.paths.{i}", f"no such configuration point: {dotted}") from None
    for name, sampler in sc.campaign.samplers.items():
        _check_sampler_range(sf, name, sampler, sc.configuration_points[name].paths)


def _check_sampler_range(sf: ScenarioFile, name: str, sampler, paths: list[str]) -> None:
    """A sampler draws only values its configuration point's fields accept (their Range)."""
    n = len(paths)
    if sampler.kind == "uniform":
        drawn = {"low": sampler.low, "high": sampler.high}
    elif sampler.kind == "simplex":  # each value lies in [minimum, total - (n - 1) * minimum]
        drawn = {"minimum": sampler.minimum, "total": sampler.total - (n - 1) * sampler.minimum}
    else:
        drawn = {f"values.{i}": v for i, v in enumerate(sampler.values) if isinstance(v, (int, float)) and not isinstance(v, bool)}
        _check_choices(sf, name, sampler, paths)
    for dotted in paths:
        valid = range_of(type_at(sf.scenario, _shortcut(sf.scenario)(dotted.split("."))))
        if valid is None:
            continue
        for key, value in drawn.items():
            if not valid.admits(value):
                raise sf.error(
                    f"campaign.samplers.{name}.{key}",
                    f"draws {value:g}, outside what {dotted} accepts: {valid}",
                )


def _check_choices(sf: ScenarioFile, name: str, sampler, paths: list[str]) -> None:
    """Each value a choice draws is one its configuration point's fields accept: set on the scenario as a run would
    set it (a value no field could take would fail the runs that draw it, after the campaign had begun)."""
    import dataclasses

    from cellsim.config.typed_yaml import apply_override, override_value

    for i, value in enumerate(sampler.values):
        text = override_value(value)
        for dotted in paths:
            trial = dataclasses.replace(sf.loaded)  # (a new value is built; the scenario's stays as it is)
            try:
                apply_override(trial, f"{dotted}={text}", _shortcut(sf.scenario))
            except ConfigError as e:
                raise sf.error(f"campaign.samplers.{name}.values.{i}",
                               f"draws {text}, which {dotted} does not accept: {e.problem}") from None


def unit_of(scenario: Scenario, dotted: str) -> str:
    """The unit of the number at ``dotted`` (``--set`` spelling; a list's element by index), or ''."""
    parts = _shortcut(scenario)(dotted.split("."))
    for n in (len(parts), len(parts) - 1):  # an element of a list of numbers: the list's range
        try:
            valid = range_of(type_at(scenario, parts[:n]))
        except ConfigError:
            continue
        if valid is not None:
            return valid.unit
    return ""


def _whole_steps(period: float, step: float) -> bool:
    ratio = period / step
    return round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-6 * ratio


def check_run_length(sf: ScenarioFile, duration: float, key: str = "duration") -> None:
    """Refuse a run whose length is out of range or whose cost would be absurd.

    ``key`` names where the duration came from: the scenario's ``duration``, or
    a command-line flag such as ``--duration``.
    """

    def refuse(problem: str) -> ConfigError:
        return sf.error(key, problem) if key == "duration" else ConfigError(key, None, "", problem)

    valid = Range(0.0, MAX_DURATION, lo_open=True, unit="s")
    if isinstance(duration, bool) or not isinstance(duration, (int, float)):
        raise refuse(f"{duration!r} is not a number of seconds")
    if not math.isfinite(duration) or not valid.admits(duration):
        raise refuse(f"{duration:g} is out of range: must be in {valid}")
    step = sf.scenario.time_step
    if duration < step:
        raise refuse(f"{duration:g} s is shorter than one plant step ({step:g} s): a run records nothing before it")
    steps = math.ceil(duration / step - 1e-9)  # a whole count: the last step may be partial
    if steps > MAX_PLANT_STEPS:
        raise refuse(
            f"{duration:g} s at a {step:g} s plant step is {steps:,} plant steps, more than the "
            f"{int(MAX_PLANT_STEPS):,} a run may take: at most {MAX_PLANT_STEPS * step:,.0f} s at this time_step, or a "
            f"time_step of at least {duration / MAX_PLANT_STEPS:.3g} s"
        )
    periods = _module_periods(sf.scenario)
    updates = math.ceil(sum(duration / p for p in periods.values()) - 1e-9)
    if updates > MAX_MODULE_UPDATES:
        busiest = sorted(periods, key=periods.get)[:3]
        listed = ", ".join(f"{name} every {periods[name]:g} s" for name in busiest)
        raise refuse(
            f"{duration:g} s is {updates:,} module updates ({listed}{', ...' if len(periods) > 3 else ''}), "
            f"more than the {int(MAX_MODULE_UPDATES):,} a run may take: shorten it or lengthen the periods"
        )


def _module_periods(sc: Scenario) -> dict[str, float]:
    """Module name -> its update period (s), for the modules updated periodically."""
    found = {}
    for section in ("entities", "behaviours", "services"):
        for name, cfg in getattr(sc, section).items():
            period = getattr(cfg, "period", None)
            if isinstance(period, float) and period > 0:
                found[name] = period
    return found


def check_seed(seed: int, key: str) -> None:
    """ConfigError naming ``key`` unless ``seed`` is a whole number in range (not a float, nor a boolean)."""
    import numbers

    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise ConfigError(key, None, "", f"{seed!r} is not a whole number: a seed is an integer in {SEEDS}")
    if not SEEDS.admits(seed):
        raise ConfigError(key, None, "", f"{seed} is out of range: must be in {SEEDS}")


def _kind(sf: ScenarioFile, key: str, cfg):
    try:
        return kind_of(cfg)
    except KindError as e:
        raise sf.error(f"{key}.kind", str(e)) from None


def value_at(scenario: Scenario, dotted: str):
    """The value at a dotted path (module names may stand for their section); KeyError if none."""
    node = to_data(scenario)
    for part in _shortcut(scenario)(dotted.split(".")):
        if isinstance(node, dict) and part in node:
            node = node[part]
        elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        else:
            raise KeyError(dotted)
    return node


def export_scenario(sf: ScenarioFile, destination_dir: str | os.PathLike | None = None) -> str:
    """The fully resolved scenario as YAML (every default written out).

    File references are rewritten relative to ``destination_dir`` (default: the
    scenario file's folder), so the exported file loads from where it is kept;
    a scenario with a base is written whole, with no base.
    """
    scenario = rebase_file_references(sf, Path(destination_dir) if destination_dir is not None else sf.base_dir)
    header = f"Resolved scenario exported by cellsim from {sf.source}"
    if sf.overrides:
        header += "\nwith overrides: " + " ".join(sf.overrides)
    return dump_yaml(scenario, header=header)


def rebase_file_references(sf: ScenarioFile, to_dir: Path) -> Scenario:
    """A copy of the scenario whose file references (each kind's ``files``) are relative to ``to_dir``.

    Each reference is read relative to the file that wrote it (the scenario or a base).
    """
    copy = from_data(Scenario, to_data(sf.scenario))
    for section in ("entities", "behaviours", "services"):
        for module, cfg in getattr(copy, section).items():
            for name in kind_of(cfg).files:
                if getattr(cfg, name) is None:
                    continue  # an optional file not given
                target = (sf.file_dir(f"{section}.{module}.{name}") / getattr(cfg, name)).resolve()
                setattr(cfg, name, os.path.relpath(target, to_dir.resolve()))
    return copy
