"""The abstract cell: what each module kind contributes, joined into one MDP.

Every module of the scenario is asked for its abstraction by its kind
(``ModuleKind.abstraction(cell, name, config)``, an :class:`Abstraction`); the
core names no kind. Building goes in two rounds, because what one module must
model depends on what the others read:

1. ``declare``: a module says which signals it reads and which numbers it
   compares with which constants (``reads``, ``compares``); a person offers the
   poses it can take (``add_person``), a sensor what it measures of them
   (``add_sensor``);
2. the floor is cut into places (``cellsim.verify.floor``) by what the read
   signals say of a person standing there; then ``build``: each module adds its
   PRISM modules and defines its output signals as PRISM formulas of the state.

A *signal* is an output port of a module, named ``<module>.<port>`` (a channel
is one), encoded as its channel type says: an enumeration's code, a boolean, or
a number's region between the thresholds it is compared with. An input port
reads whatever the cell's Diagram connects to it (Drake's own connection map,
not a second reading of the scenario), else its declared default.

The time step is one period of the safety controller (the fastest supervisor).
Every module updates at its own period, on that grid, as in the twin (every
module's updates fall on multiples of its period from t = 0): a module of twice
the step updates every other step, and a clock (``tick``, counting the steps
modulo the periods' least common multiple) says when. All read the state before
the step, as the Diagram's discrete updates do. A sensor's readings are state,
taken at its own period from where the people are, so whoever reads them reads
them a step later at the earliest, as the twin's controller does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Protocol

from cellsim.verify.expressions import Encoding, Thresholds, VerifyError
from cellsim.verify.order import ordered
from cellsim.verify.prism import Command, Enum, Module, Program, Var

TICK = "tick"
"""The clock's variable: the step's number modulo the least common multiple of the modules' periods (in steps)."""

CODE = Enum(())
"""The encoding of a port that is not a channel: its integer code, as the systems exchange it."""


class Abstraction(Protocol):
    """What a module kind offers ``verify``: one object per module."""

    def declare(self, cell: "AbstractCell") -> None:
        """Say what the module reads and compares; offer poses (a person) or measurements (a sensor)."""

    def build(self, cell: "AbstractCell") -> None:
        """Add the module's PRISM modules and define its output signals."""


def declare_for_readers(part, cell: "AbstractCell") -> None:
    """Round 1, last: once every module and condition has said what it reads, a module whose signal is costly to
    model (a true separation: distances measured at every pose of the floor) declares what it needs for the signals
    somebody reads (``declare_for_readers(cell)``, where its abstraction has one)."""
    late = getattr(part, "declare_for_readers", None)
    if late is not None:
        late(cell)


@dataclass(frozen=True)
class Pose:
    """Where a person can stand, facing ``yaw`` (rad), reaching towards ``reach`` (a point, m) or not."""

    x: float
    y: float
    yaw: float
    reach: tuple[float, float, float] | None = None


@dataclass
class PersonRole:
    """A person: the poses it can take, and the signals of its own that follow from its pose."""

    module: str
    poses: list[Pose]
    """Candidate poses (a grid over the floor it can walk, with headings and reaches)."""
    start: Pose
    stand: Callable[[object, Pose | None], None]
    """Put the person at a pose in a root context of the cell (None: far away, seen by nobody)."""
    own: dict[str, Callable[[Pose], object]] = field(default_factory=dict)
    """Port -> its value (in the channel's words) at a pose (the zone stood in, a flag)."""
    step: float = 0.1
    """The grid's step (m): poses this near (or at one point) are neighbours."""
    buttons: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Output port -> where the person stands to press that button (it may press it there)."""
    travel: Callable[[Pose, Pose], float] | None = None
    """Seconds it takes to walk from one pose to another (for a witness's timing)."""
    walk: Callable[..., dict] | None = None
    """``walk(start, stops, presses)``: its scenario config keys for a witness walk (see ``cellsim.verify.witness``)."""
    max_speed: float | None = None
    """m/s: the fastest the person walks, where its pace is modelled (a place then takes the periods its crossing
    takes at that speed); None: any pace (a place may be crossed in one period)."""
    top_speed: float | None = None
    """m/s: the fastest the person walks in the twin, pace modelled or not: the model takes its place at its own
    period only where it cannot walk past a grid point in one (else at every step); None: at every step."""
    end: Pose | None = None
    """Where its script leaves it at the end of the run (its last stop, arm down), when the script is over by then
    at its slowest pace: a ``Final`` condition (``F G p``) is judged where every person stands there."""
    ends: str = ""
    """Where and by when it gets to ``end`` (words for the assumption), or why there is no ``end``."""
    refines: float | None = None
    """The step (m) of a coarser grid this one halves, measured before it (a refinement's round): a new point whose
    neighbours on that grid, at its heading and reach, all read the same reads as they do, unmeasured
    (:func:`cellsim.verify.floor.cut_floor`); None: every pose is measured."""


@dataclass
class SensedSignal:
    """A signal a sensor measures of the people: ``measure(root_context)`` with them as posed (or, where the
    sensor's role has its own ``measure``, ``measure(that measurement)``)."""

    measure: Callable[[object], object]
    combine: Callable[[list], object] | None
    """The reading of several people from each one's alone (nearest, any...), on values in the channel's words
    (a number: in its unit); None: a measurement of each person alone, never combined (only its
    ``<signal>.of_<person>`` formulas are defined, for the module that asked for it)."""
    cuts: bool = True
    """Whether the floor is cut where it changes (a sensor's reading: each place reads one value). False: a lower bound
    of a distance (m) from the person's body, which moves no more than the body does, that cuts nothing; each place
    reads the least of its poses' values (``Place.least``: where), an over-approximation that adds no state (a
    contact's clearance)."""


@dataclass
class SensorRole:
    module: str
    signals: dict[str, SensedSignal]
    measure: Callable[[object], object] | None = None
    """The sensor's one measurement of the people as posed (``measure(root_context)``), when several of its signals
    come from it: the floor then measures once per pose and each signal's ``measure`` takes that measurement (an area
    scanner's field and distance from one scan)."""


@dataclass
class Property:
    """A property the abstract model is checked for.

    A safety property asks for the largest probability, over every way the
    nondeterminism (the people, the robot's pace) resolves, of reaching ``bad``
    states: it holds when that is 0. A user's PCTL property (``pctl``) is
    checked as written.
    """

    name: str
    description: str
    bad: str = ""
    """PRISM expression of the states that violate it (a safety property)."""
    pctl: str = ""
    """A user's own PCTL (with PRISM expressions): reported as Storm computes it."""
    hazard: tuple[str, str] | None = None
    """(channel, value): reaching this value is the violation the twin must show (a mishap)."""
    condition: str | None = None
    """The validation condition whose violation the twin must show."""
    sustained: str = ""
    """PRISM expression of the bad states where the violation lasted its whole window (a bounded response):
    the witness sought first, as it holds whatever the order of events within a period; an invariant's, where it
    fails on its signals' firm formulas too (``Signal.firm``)."""
    within: float | None = None
    """A liveness condition ``G(a -> F b)``, checked as the stronger ``G(a -> F[0, within] b)`` (s): holding proves
    the condition; failing says only that ``b`` may take longer (then judged under fairness, ``response``)."""
    final: bool = False
    """A ``Final`` condition (``F G p``): its bad states are where each person stands at its script's end, so a witness
    walk ends at that very stop (``PersonRole.end``)."""
    response: tuple[str, str] | None = None
    """A liveness condition's ``a`` and ``b`` (PRISM expressions): whether ``b`` can still come from every state
    reachable from ``a`` without it (:func:`cellsim.verify.storm.always_answerable`)."""
    obligation: tuple[str, str, str, int] | None = None
    """A bounded obligation ``G(a -> (b U[0, n] c))`` (``a``, ``b``, ``c`` PRISM expressions, ``n`` periods) whose bad
    states a monitor module follows (``bad`` reads it): the whole cell's decision diagrams, built without monitors,
    check it as a nested formula instead (:func:`cellsim.verify.storm.obligation_formula`)."""
    ends: int = 1
    """A liveness condition: how many labels ``<label>_end<k>`` say where the people may stand when a run ends, each
    one way they may stand there (:func:`cellsim.verify.storm.owed_at_the_end`); 0: too many ways to ask."""


@dataclass(frozen=True)
class Signal:
    name: str
    formula: str
    """The PRISM formula's name that carries it."""
    encoding: Encoding
    firm: str | None = None
    """Where the formula over-approximates (a value the cell may or may not have there), the name of a formula that
    reads that value only where the cell most likely has it: a property's witness is sought first among the states
    where it fails on the firm formulas too (``Property.sustained``), so that the twin is handed the likelier one."""


def prism_name(signal: str) -> str:
    """The PRISM identifier of a signal ``module.port``."""
    return signal.replace(".", "__")


class Observer:
    """The abstraction of a module that only watches (a recorder, a ground truth): it adds nothing."""

    def declare(self, cell: "AbstractCell") -> None:
        """Reads nothing."""

    def build(self, cell: "AbstractCell") -> None:
        """Adds nothing: a signal only it publishes has no abstraction (what reads it is left out)."""



def context_of(system):
    """``root context -> system's context``: how an abstraction calls its system's own measurements."""
    return lambda root: system.GetMyContextFromRoot(root)


def nearest(order):
    """``values -> the one first in order``: how a sensor combines several people's readings (the most restrictive)."""
    return lambda values: min(values, key=order.index)


class AbstractCell:
    """The abstract model under construction, over a built cell (``cellsim.diagrams.cell.CellDiagram``)."""

    def __init__(self, cell, period: float, timed: bool = False, refinements: frozenset = frozenset()):
        self.cell = cell
        self.timed = timed
        """Whether the cell's own durations (moves, dwells, cycles) are bounded below in every module; without,
        each may take any number of periods from one on (more behaviours, far fewer states) unless a module's
        refinement bounds its own (:meth:`ModuleAbstraction.timed`)."""
        self.refinements = frozenset(refinements)
        """The refinements switched on (``<module>:<what>``, e.g. ``operator:pace``): what each module's abstraction
        models more finely because a witness showed where it was too coarse
        (:meth:`ModuleAbstraction.refinement`)."""
        self.sf = cell.sf
        self.period = period
        self.modules: list[Module] = []
        self.formulas: dict[str, str] = {}
        self.labels: dict[str, str] = {}
        self.signals: dict[str, Signal] = {}
        self.reads: dict[str, str] = {}
        """Signal read -> who reads it (for errors)."""
        self.required: set[str] = set()
        self.thresholds: dict[str, set[float]] = {}
        self.signed: dict[str, set[tuple[str, bool]]] = {}
        """Signal -> how the conditions compare it with numbers: (operator, polarity: whether the condition is the
        likelier to hold the likelier the comparison holds; ``cellsim.logic.syntax.signed_comparisons``)."""
        self.people: list[PersonRole] = []
        self.sensors: list[SensorRole] = []
        self.assumptions: list[str] = []
        self.properties: list[Property] = []
        self.unmodelled: dict[str, str] = {}
        """Signal -> why its module leaves it out of the model (where that says more than 'no abstraction models it')."""
        self.internal: dict[str, Encoding] = {}
        """A signal that is no port of the cell (a sensor's raw measurement) -> its encoding."""
        self.monitors: dict[str, Module] = {}
        """Property name -> the monitor module only that property reads (checked in a model of its own)."""
        self.places = None
        """After ``declare``: the floor's places (``cellsim.verify.floor.Places``)."""
        self.building: str | None = None
        """The module whose abstraction is building (round 2): the PRISM modules it adds update at its period."""
        self.slower: dict[str, int] = {}
        """The cell's modules whose PRISM modules update less often than every step -> every how many steps."""
        self.types = {name: spec.type for name, (spec, _) in cell.channels.items()}
        self.connections: dict[tuple[str, str], str] = {}
        for (sys_in, i), (sys_out, o) in cell.diagram.connection_map().items():
            self.connections[(sys_in.get_name(), sys_in.get_input_port(i).get_name())] = (
                f"{sys_out.get_name()}.{sys_out.get_output_port(o).get_name()}"
            )

    # -- round 1 -----------------------------------------------------------------------
    def read(self, signal: str, by: str, required: bool = True) -> str:
        """The PRISM formula carrying ``signal`` (defined by its module in round 2).

        A signal read but not ``required`` (a validation condition's) may stay undefined:
        whatever reads it is then left out, with the reason."""
        self.reads.setdefault(signal, by)
        if required:
            self.required.add(signal)
        return prism_name(signal)

    def compares(self, signal: str, values) -> None:
        """``signal`` (a number) is compared with these constants: its regions keep them apart."""
        self.thresholds.setdefault(signal, set()).update(float(v) for v in values)

    def add_person(self, role: PersonRole) -> None:
        self.people.append(role)

    def add_sensor(self, role: SensorRole) -> None:
        self.sensors.append(role)

    def assume(self, text: str) -> None:
        """An assumption of this abstraction, stated with every result."""
        if text not in self.assumptions:
            self.assumptions.append(text)

    # -- round 2 -----------------------------------------------------------------------
    def encoding(self, signal: str) -> Encoding:
        """How ``signal`` is encoded: its channel's enumeration, bool, or its thresholds."""
        if signal in self.signals:
            return self.signals[signal].encoding
        if signal in self.internal:
            return self.internal[signal]
        ctype = self.types.get(signal)
        if ctype is None:
            raise VerifyError(f"'{signal}' is not a channel of the cell")
        return self.encoding_of(signal, ctype)

    def encoding_of(self, signal: str, ctype) -> Encoding:
        if ctype.kind == "enum":
            return Enum(tuple(ctype.domain()))
        if ctype.kind == "bool":
            return bool
        return Thresholds(tuple(sorted(self.thresholds.get(signal, ()))))

    def define(self, signal: str, expr: str, encoding: Encoding | None = None, firm: str | None = None) -> str:
        """``signal`` is ``expr`` (codes of its encoding); returns its formula's name. ``firm``: where ``expr``
        over-approximates, the likelier reading (``Signal.firm``)."""
        if signal in self.signals:
            raise VerifyError(f"signal '{signal}' is defined twice in the abstract model")
        name = prism_name(signal)
        encoding = encoding if encoding is not None else self.encoding(signal)
        if firm is not None:
            self.formulas[f"{name}_firm"] = firm
        self.signals[signal] = Signal(signal, name, encoding, None if firm is None else f"{name}_firm")
        self.formulas[name] = expr
        return name

    def input(self, module: str, port: str, by: str | None = None) -> str:
        """The expression an input port reads: the signal connected to it, else its default code."""
        source = self.connections.get((module, port))
        if source is not None:
            return self.read(source, by or module)
        system = self.cell.modules[module]
        default = getattr(system, "input_defaults", {}).get(port)
        if default is None:
            raise VerifyError(f"input '{module}.{port}' is driven by nothing and has no default")
        return str(int(default))

    def every(self, module: str) -> int:
        """Steps between a module's updates: its period over the step. A period that is no whole multiple of the step
        is refused: the model could not take the module's updates when the twin does."""
        period = getattr(self.cell.modules.get(module), "period", None)
        if period is None:
            return 1
        steps = round(period / self.period)
        if steps < 1 or abs(steps * self.period - period) > 1e-9 * max(1.0, period):
            raise VerifyError(f"{module} updates every {period:g} s, which is no whole multiple of the model's step "
                              f"({self.period:g} s, the fastest supervisor's period): the abstract model cannot take "
                              "its updates when the twin does; give it a period that is")
        return steps

    def initial_code(self, signal: str) -> int:
        """The code of the value the twin's module publishes on channel ``signal`` before its first update."""
        module, port = signal.split(".", 1)
        built = self.cell
        context = built.diagram.CreateDefaultContext()
        built.set_initial_state(context)
        system = built.modules[module]
        value = self.types[signal].decode(system.GetMyContextFromRoot(context).get_discrete_state(
            system.group(port)).get_value())
        if value is None:
            raise VerifyError(f"{signal} starts with no value: the abstract model has no code for its first reading")
        return self.code_of(signal, value)

    def code_of(self, signal: str, value) -> int:
        """The code of ``value`` (in the channel's words; a number in its unit) in ``signal``'s encoding."""
        encoding = self.encoding(signal)
        if isinstance(encoding, Thresholds):
            return encoding.region_of(float(value))
        if encoding is bool:
            return int(bool(value))
        return encoding.code(value.value if hasattr(value, "value") else value)

    def add(self, module: Module, every: int | None = None, owner: str | None = None) -> None:
        """Add a PRISM module of ``owner``'s (default: the module whose abstraction is building), updated every
        ``every`` steps (default: at the owner's period; no owner: every step)."""
        owner = owner or self.building
        if every is None:
            every = self.every(owner) if owner else 1
        if every > 1:
            self.slower[owner or module.name] = every
            module = on_its_phase(module, every)
        self.modules.append(module)

    def clock(self) -> Module | None:
        """The clock the modules' phases read (None: every module updates every step)."""
        if not self.slower:
            return None
        steps = math.lcm(*self.slower.values())
        return Module("clock", [Var(TICK, 0, steps - 1, 0)], [Command("true", (("1", {TICK: f"mod({TICK}+1, {steps})"}),))],
                      comment=f"the step's number modulo {steps}: a module of k steps updates where it is a multiple of k")

    def program(self, header: str = "", monitors: list[str] | None = None, labels: dict[str, str] | None = None) -> Program:
        """The cell's modules, with the monitors named (default: all), and the labels given (default: all)."""
        missing = sorted(s for s in self.required if s not in self.signals)
        if missing:
            signal = missing[0]
            raise VerifyError(f"{self.reads[signal]} reads '{signal}', which no module's abstraction defines")
        chosen = [self.monitors[m] for m in (self.monitors if monitors is None else monitors)]
        clock = self.clock()
        modules = ordered([*([clock] if clock else []), *self.modules, *chosen], self.formulas)  # the order that keeps decision diagrams small
        return Program(modules, dict(self.formulas), dict(self.labels if labels is None else labels), header)


def on_its_phase(module: Module, every: int) -> Module:
    """``module`` updated only at the steps that are multiples of ``every``: each command where the clock says so,
    and at the other steps a command that keeps its state."""
    now = f"mod({TICK}, {every})=0"
    commands = [replace(c, guard=now if c.guard.strip() == "true" else f"({c.guard}) & {now}") for c in module.commands]
    commands.append(Command(f"mod({TICK}, {every})!=0", (("1", {}),)))
    comment = module.comment + ("\n" if module.comment else "") + f"updates every {every} steps (its own period)"
    return Module(module.name, module.variables, commands, comment)


def translate(expr: str, source: Encoding, target: Encoding) -> str:
    """``expr`` (codes of ``source``) as codes of ``target``: enumerations by value name; -1 stays -1."""
    if source == target:
        return expr
    if isinstance(source, Enum) and isinstance(target, Enum):
        # a value the target does not know reads -1, which no guard's value equals (as in the engine)
        cases = [(source.code(v), target.code(v) if v in target.values else -1) for v in source.values]
        return _lookup(expr, cases, -1)
    if isinstance(source, Enum) and target is bool:
        return f"({expr} = {source.code('true') if 'true' in source.values else 1})"
    if source is bool and isinstance(target, Enum):
        return f"({expr} ? 1 : 0)"
    raise VerifyError(f"cannot translate {source} into {target}")


def _lookup(expr: str, cases: list[tuple[int, int]], otherwise: int) -> str:
    """``expr = a1 ? b1 : expr = a2 ? b2 : ... : otherwise`` (identity pairs folded)."""
    if all(a == b for a, b in cases) and otherwise == -1:
        return expr
    out = str(otherwise)
    for a, b in reversed(cases):
        out = f"({expr} = {a} ? {b} : {out})"
    return out


def lookup(expr: str, table: dict[int, int], otherwise: int) -> str:
    """A PRISM expression mapping ``expr``'s value through ``table``, grouped by result (a search tree over the
    value where the table has many runs, :func:`_tree`)."""
    tree = _tree(expr, {k: str(v) for k, v in table.items()}, str(otherwise))
    if tree is not None:
        return tree
    groups: dict[int, list[int]] = {}
    for key, value in sorted(table.items()):
        if value != otherwise:
            groups.setdefault(value, []).append(key)
    out = str(otherwise)
    for value, keys in sorted(groups.items(), reverse=True):
        out = f"({_any_of(expr, keys)} ? {value} : {out})"
    return out


def set_of(expr: str, keys) -> str:
    """A PRISM condition: ``expr`` is one of ``keys`` (a search tree over the value where they make many runs)."""
    keys = sorted(set(keys))
    if not keys:
        return "false"
    return _tree(expr, dict.fromkeys(keys, "true"), "false") or _any_of(expr, keys)


TREE_FROM = 8
"""Runs of equal values (keys in a row) from which a lookup or a set is written as a search tree over the key:
Storm's state-by-state builder evaluates every test of a chain (a place's reading: a few dozen) where a tree asks
a handful. Fewer runs keep the chain, which reads better in an exported model."""


def _tree(expr: str, table: dict[int, str], otherwise: str) -> str | None:
    """``table[expr]`` (``otherwise`` for any other value) as nested ``expr<k ? a : b``, one test per level; None when
    the table has fewer than ``TREE_FROM`` runs."""
    keys = sorted(table)
    if not keys or keys[-1] - keys[0] > 100_000:  # (codes and places span a few hundred values at most)
        return None
    runs: list[tuple[int | None, str]] = [(None, otherwise)]  # (first key of the run, its value); None: from -inf
    for k in range(keys[0], keys[-1] + 2):
        value = table.get(k, otherwise)
        if value != runs[-1][1]:
            runs.append((k, value))
    if len(runs) < TREE_FROM:
        return None

    def split(i: int, j: int) -> str:
        if j - i == 1:
            return runs[i][1]
        middle = (i + j) // 2
        return f"({expr}<{runs[middle][0]} ? {split(i, middle)} : {split(middle, j)})"

    return split(0, len(runs))


def _any_of(expr: str, keys: list[int]) -> str:
    # runs of consecutive keys as ranges: fewer terms for Storm to parse
    parts, start = [], None
    for i, k in enumerate(keys):
        if start is None:
            start = k
        if i + 1 == len(keys) or keys[i + 1] != k + 1:
            parts.append(f"{expr}={k}" if start == k else f"({expr}>={start}&{expr}<={k})")
            start = None
    return "(" + "|".join(parts) + ")"


class ModuleAbstraction:
    """What a kind's abstraction of one module starts from: its name, config and built system.
    ``declare`` (round 1: what it reads, its people and sensors) and ``build`` (round 2: its
    PRISM modules and signals) do nothing unless the kind says otherwise."""

    def __init__(self, cell: AbstractCell, name: str, cfg):
        self.name, self.cfg = name, cfg
        self.system = cell.cell.modules[name]

    def declare(self, cell: AbstractCell) -> None:
        pass

    def build(self, cell: AbstractCell) -> None:
        pass

    def refinement(self, cell: AbstractCell, witness: list[dict]) -> tuple | None:
        """Where a witness does what this module cannot (asked before the witness is run on the twin: a witness some
        module faults is refined, not run): ``(refinement, why, step)``, the refinement (``<module>:<what>``) that
        models it more finely, which variable at which period shows it, and the witness's step where it departs from
        the cell, the first state the cell cannot be in (the loop refines where the witness departs first;
        ``(refinement, why)``: at its end), or None
        (nothing of this module's). ``witness``: the model's variables at each step."""
        return None

    def chooses_pose_for(self, prop) -> bool:
        """Whether this module says where a witness of ``prop`` leaves its people (:meth:`witness_pose`): a replay
        of another property's witness on the same path is then not this one's (``cellsim.verify.witness.walk_key``)."""
        return False

    def witness_pose(self, cell: "AbstractCell", prop, person, place: int, state: dict):
        """Where ``person`` (``PersonPlaces``) should stand in ``place``, the last of a witness of ``prop`` ending in
        the model's ``state``, for the twin to show what the model found there; None (the default): the replay's
        own choice (the place's inner pose nearest the last stop)."""
        return None

    def leaves_unrefined(self, prop) -> str | None:
        """Why a refuted witness of ``prop`` should refine nothing (no refinement of any module tightens what makes
        this module's reading of it coarse), in words; None (the default): the loop refines as the modules offer."""
        return None

    def timed(self, cell: AbstractCell) -> bool:
        """Whether this module's own durations (a move, a dwell, a cycle) are bounded below in the model: in every
        module (``--timed``), or in this one, refined (``<module>:timed``) where a witness was faster than it."""
        return cell.timed or f"{self.name}:timed" in cell.refinements


def runs_of(witness: list[dict], variable: str) -> list[tuple[object, int, int]]:
    """The witness's runs of one variable's value: (value, first step, last step), in order (none if the witness
    does not have it)."""
    runs: list[list] = []
    for k, state in enumerate(witness):
        if variable not in state:
            return []
        if runs and runs[-1][0] == state[variable]:
            runs[-1][2] = k
        else:
            runs.append([state[variable], k, k])
    return [tuple(r) for r in runs]


def updates_in(first: int, last: int, every: int) -> int:
    """How many updates a module taken every ``every`` steps (from step 0) makes from the states ``first`` to
    ``last`` of a witness: the steps k in that range with k a multiple of ``every`` (each takes state k to k + 1)."""
    return sum(1 for k in range(first, last + 1) if k % every == 0)
