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

import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Literal

from cellsim.config.typed_yaml import (
    ConfigError,
    FieldError,
    Loaded,
    apply_overrides,
    dump_yaml,
    from_data,
    load_file,
    to_data,
)
from cellsim.campaign.samplers import Sampler
from cellsim.registry import BehaviourModule, EntityModule, KindError, ServiceModule, kind_of
from cellsim.validation.config import Validation
from cellsim.vocabulary import RobotActivity, RobotLocation, TwinMode

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]
Rgba = tuple[float, float, float, float]


# -- layout -------------------------------------------------------------------
@dataclass
class Fixture:
    """A static box in the cell (table, bench, fence panel, machine body)."""

    size: Vec3
    center: Vec3
    yaw_deg: float = 0.0
    color: Rgba = (0.55, 0.55, 0.58, 1.0)

    def __post_init__(self):
        if min(self.size) <= 0:
            raise FieldError("size", "every dimension must be positive")


@dataclass
class Region:
    """An axis-aligned box of space, [min, max] per axis."""

    min: Vec3
    max: Vec3

    def __post_init__(self):
        if any(lo >= hi for lo, hi in zip(self.min, self.max)):
            raise FieldError("max", "each coordinate of max must exceed min")

    def contains(self, p) -> bool:
        return all(lo <= x <= hi for lo, x, hi in zip(self.min, p, self.max))


@dataclass
class Layout:
    fixtures: dict[str, Fixture] = field(default_factory=dict)
    robot_regions: dict[str, Region] = field(default_factory=dict)
    """Where the robot's tool counts as atTable, sharedTbl or atWeldSpot; elsewhere inCell."""
    cell: Region = field(default_factory=lambda: Region((-1.3, -1.6, 0.0), (2.0, 1.6, 2.5)))
    """The safeguarded cell: an operator standing in it is ``inCell``."""
    shared_table_zone: Region = field(default_factory=lambda: Region((-2.0, -0.5, 0.0), (-1.3, 0.5, 2.5)))
    """Where an operator standing counts as at the shared table (``otab``)."""

    def __post_init__(self):
        allowed = {m.value for m in RobotLocation} - {RobotLocation.IN_CELL.value}
        for name in self.robot_regions:
            if name not in allowed:
                raise FieldError(
                    f"robot_regions.{name}",
                    f"'{name}' is not a robot location with a region (one of: {', '.join(sorted(allowed))})",
                )


# -- entities -----------------------------------------------------------------
@dataclass
class TwinModeChange:
    at: float
    mode: TwinMode


@dataclass
class TwinSettings:
    """How an entity relates to its physical twin, and when that changes."""

    mode: TwinMode = TwinMode.MODEL
    changes: list[TwinModeChange] = field(default_factory=list)
    stale_after: float = 0.5
    """A physical sample older than this (s) is stale: the entity fails safe."""

    def __post_init__(self):
        times = [c.at for c in self.changes]
        if times != sorted(times):
            raise FieldError("changes", "twin-mode changes must be in time order")
        if self.stale_after <= 0:
            raise FieldError("stale_after", "must be positive")


@dataclass
class SpeedLimits:
    """Cap on the tool's speed (m/s) in each moving safety mode; srmst and stopped are standstill."""

    normal: float = 1.0
    hguid: float = 0.25
    ssmon: float = 0.5
    pflim: float = 0.25


@dataclass
class RobotConfig:
    kind: Literal["robot"]
    model: str
    """URDF of the arm, relative to the scenario file."""
    named_poses: dict[str, list[float]]
    """Joint positions (rad) of the poses the process moves between."""
    base_position: Vec3 = (0.0, 0.0, 0.0)
    """Where the arm's base_link is fixed in the cell (m)."""
    base_yaw_deg: float = 0.0
    """Rotation of the base about the vertical axis (degrees)."""
    tool_frame: str = "tcp"
    """The frame of the model whose position gives the robot's location and tool speed."""
    initial_pose: str = "home"
    """The named pose the arm starts in."""
    speed_limits: SpeedLimits = field(default_factory=SpeedLimits)
    """Tool speed cap per moving safety mode (m/s)."""
    braking_time: float = 0.5
    """Time to standstill from full speed on srmst or stopped (s)."""
    period: float = 0.02
    """Update period of the controller side (s); a multiple of the plant step."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        if self.initial_pose not in self.named_poses:
            raise FieldError("initial_pose", f"'{self.initial_pose}' is not one of the named_poses")
        for name, q in self.named_poses.items():
            if len(q) != 6:
                raise FieldError(f"named_poses.{name}", f"needs 6 joint positions, got {len(q)}")
        if self.braking_time <= 0:
            raise FieldError("braking_time", "must be positive")


@dataclass
class WelderConfig:
    kind: Literal["welder"]
    period: float = 0.04
    """Update period (s)."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""


@dataclass
class LightBarrierConfig:
    """A light curtain; its beams fill a box, broken while a person's geometry is in it."""

    kind: Literal["light_barrier"]
    center: Vec3
    """Centre of the box the beams fill (m)."""
    size: Vec3
    """Size of that box along x, y, z (m)."""
    period: float = 0.04
    """Response time (s). People move every 40 ms in the twin; sampling faster reads the same geometry."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""


@dataclass
class RangeDetectorConfig:
    """A safety scanner: far / near / close from the nearest person's distance to it."""

    kind: Literal["range_detector"]
    position: Vec3
    """Where the scanner head is (m); distances are measured from it."""
    near_below: float = 2.0
    """Below this distance (m) the range reads near."""
    close_below: float = 1.0
    """Below this distance (m) the range reads close."""
    noise_std: float = 0.0
    """Standard deviation of the measured distance (m); drawn from the run's seed."""
    period: float = 0.04
    """Response time (s)."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        if not 0 < self.close_below < self.near_below:
            raise FieldError("close_below", "needs 0 < close_below < near_below")
        if self.noise_std < 0:
            raise FieldError("noise_std", "must not be negative")


@dataclass
class Waypoint:
    position: Vec2
    wait: float = 0.0
    """Seconds spent at the waypoint."""
    reach: Vec3 | None = None
    """A point the operator reaches for with one hand while waiting here."""

    def __post_init__(self):
        if self.wait < 0:
            raise FieldError("wait", "must not be negative")


@dataclass
class OperatorConfig:
    """A person walking an ordered list of waypoints, with body geometry."""

    kind: Literal["operator"]
    start: Vec2
    """Where the person stands at t = 0 (x, y in m)."""
    waypoints: dict[str, Waypoint]
    """The places walked to, in order, each with a wait and an optional reach."""
    start_delay: float = 0.0
    """Seconds before the person starts walking."""
    walking_speed: float = 1.2
    """Mean walking speed (m/s)."""
    speed_jitter: float = 0.1
    """Each leg's speed is drawn uniformly within +-this fraction, from the run's seed."""
    height: float = 1.75
    """Body height (m)."""
    body_radius: float = 0.2
    """Radius of the torso's capsule (m)."""
    arm_length: float = 0.7
    """Reach of the arm from the shoulder (m)."""
    period: float = 0.04
    """Update period (s): how often the body moves in the twin."""
    twin: TwinSettings = field(default_factory=TwinSettings)
    """Its twin mode (model, shadow, twin), scheduled changes and when samples go stale."""

    def __post_init__(self):
        if self.walking_speed <= 0:
            raise FieldError("walking_speed", "must be positive")
        if not 0 <= self.speed_jitter < 1:
            raise FieldError("speed_jitter", "must be in [0, 1)")




# -- behaviours ---------------------------------------------------------------
@dataclass
class WorkStep:
    """One step of the work cycle: a move, a dwell or a weld, with the robot's activity."""

    name: str
    move_to: str | None = None
    dwell: float = 0.0
    weld: float = 0.0
    activity: RobotActivity = RobotActivity.EXCHANGE_WORKPIECE

    def __post_init__(self):
        if sum(x is not None and x != 0 for x in (self.move_to, self.dwell or None, self.weld or None)) != 1:
            raise FieldError("name", f"step '{self.name}' must have exactly one of move_to, dwell, weld")


@dataclass
class WorkCycleConfig:
    """The process controller: repeats its steps while the safety mode permits."""

    kind: Literal["work_cycle"]
    steps: list[WorkStep]
    """The cycle's steps, in order: each a move_to a named pose, a dwell or a weld."""
    robot: str = "robot"
    """The robot entity the cycle moves."""
    welder: str = "welder"
    """The welder entity it asks to weld."""
    restart_on_request: dict[str, str] = field(default_factory=dict)
    """Robot activity requested by the safety controller -> step the cycle restarts from."""
    period: float = 0.04
    """Update period (s)."""

    def __post_init__(self):
        names = [s.name for s in self.steps]
        if not names:
            raise FieldError("steps", "needs at least one step")
        for activity, step in self.restart_on_request.items():
            if activity not in RobotActivity.names():
                raise FieldError(f"restart_on_request.{activity}", f"'{activity}' is not a robot activity")
            if step not in names:
                raise FieldError(f"restart_on_request.{activity}", f"'{step}' is not a step of the cycle")


@dataclass
class SafetyControllerConfig:
    """The risk-model safety controller: a generic engine executing a risk model file."""

    kind: Literal["safety_controller"]
    risk_model: str
    """Risk model YAML, relative to the scenario file."""
    monitors: dict[str, str]
    """Risk-model variable -> channel it reads (``module.signal``)."""
    commands: dict[str, list[str]]
    """Controlled variable -> command inputs it drives (``module.input``)."""
    period: float = 0.02
    """Control period (s): how often the risk model is evaluated."""


@dataclass
class GroundTruthConfig:
    """Measures what no sensor reports: the true operator-robot separation."""

    kind: Literal["ground_truth"]
    period: float = 0.1
    """How often the separation is measured (s)."""




# -- services -----------------------------------------------------------------
@dataclass
class RecorderConfig:
    """The message snooper: writes every message to the black box (SQLite)."""

    kind: Literal["blackbox"]
    batch_size: int = 5000
    """Rows buffered before they are written within one drain (memory bound)."""




@dataclass
class ConfigurationPoint:
    """A named, documented value of the scenario that runs may vary."""

    paths: list[str]
    description: str = ""


@dataclass
class CampaignConfig:
    """Defaults of ``cellsim campaign``: how many runs, and how each configuration point is drawn."""

    runs: int = 100
    samplers: dict[str, Sampler] = field(default_factory=dict)
    """Configuration point name -> sampler (``uniform``, ``choice`` or ``simplex``)."""

    def __post_init__(self):
        if self.runs < 1:
            raise FieldError("runs", "must be at least 1")


@dataclass
class Scenario:
    name: str
    layout: Layout
    entities: dict[str, EntityModule]
    """Module name -> its config; ``kind`` names its module kind (``cellsim modules`` lists them)."""
    behaviours: dict[str, BehaviourModule] = field(default_factory=dict)
    services: dict[str, ServiceModule] = field(default_factory=dict)
    configuration_points: dict[str, ConfigurationPoint] = field(default_factory=dict)
    validation: Validation = field(default_factory=Validation)
    campaign: CampaignConfig = field(default_factory=CampaignConfig)
    description: str = ""
    duration: float = 30.0
    seed: int = 0
    time_step: float = 0.002
    """The robot plant's discrete step (s): 2 ms, the 500 Hz of a UR controller's joint loop."""

    def __post_init__(self):
        seen: dict[str, str] = {}
        for section in ("entities", "behaviours", "services"):
            for name in getattr(self, section):
                if name in seen:
                    raise FieldError(f"{section}.{name}", f"module name '{name}' is already used in {seen[name]}")
                if not name.isidentifier():
                    raise FieldError(f"{section}.{name}", "module names must be identifiers (letters, digits, _)")
                seen[name] = section
        if self.duration <= 0:
            raise FieldError("duration", "must be positive")
        if not 0 < self.time_step <= 0.01:
            raise FieldError("time_step", "must be in (0, 0.01] s")

    def modules_of_kind(self, kind: str) -> dict[str, object]:
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

    @property
    def scenario(self) -> Scenario:
        return self.loaded.value

    @property
    def source(self) -> str:
        return self.loaded.source

    @property
    def base_dir(self) -> Path:
        return Path(self.loaded.source).resolve().parent

    def error(self, key: str, problem: str) -> ConfigError:
        """A ConfigError at ``key`` (dotted path), naming the file (the scenario or a base) and line."""
        return ConfigError(*self.loaded.where(key), key, problem)

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

    def resolve_path(self, key: str, relative: str) -> Path:
        """An existing file named at ``key``, relative to the file that names it."""
        path = Path(relative)
        if not path.is_absolute():
            path = self.file_dir(key) / path
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
    loaded = load_file(Scenario, path, base_key="base")
    apply_overrides(loaded, list(overrides), resolve=_shortcut(loaded.value))
    sf = ScenarioFile(loaded, list(overrides))
    _load_validation_file(sf)
    check_scenario(sf)
    return sf


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
            if kind.check is not None:
                kind.check(sf, name, cfg)
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


class _FileFieldsByConfig:
    """``FILE_FIELDS.get(ConfigClass)``: the file fields of the kind whose config that class is.

    Transitional: prefer ``kind_of(cfg).file_fields``.
    """

    def get(self, config_type, default=()):
        import typing

        from cellsim import registry

        (name,) = typing.get_args(typing.get_type_hints(config_type)["kind"])
        kind = registry.get(name)
        return kind.file_fields if kind.config is config_type else default


FILE_FIELDS = _FileFieldsByConfig()


def rebase_file_references(sf: ScenarioFile, to_dir: Path) -> Scenario:
    """A copy of the scenario whose file references (each kind's ``file_fields``) are relative to ``to_dir``.

    Each reference is read relative to the file that wrote it (the scenario or a base).
    """
    copy = from_data(Scenario, to_data(sf.scenario))
    for section in ("entities", "behaviours", "services"):
        for module, cfg in getattr(copy, section).items():
            for name in kind_of(cfg).file_fields:
                target = (sf.file_dir(f"{section}.{module}.{name}") / getattr(cfg, name)).resolve()
                setattr(cfg, name, os.path.relpath(target, to_dir.resolve()))
    return copy
