"""The floor cut into places: where a person stands, as far as the cell can tell.

Each person offers candidate poses (a grid over the floor it can walk, with
headings and reaches: ``PersonRole.poses``). Standing the person at each pose in
a context of the built cell, alone, every signal someone reads is measured: the
person's own (the zone, a flag) and every sensor's, through the sensors' own
SceneGraph queries. Poses that read the same and touch (same point, or grid
neighbours) form one *place*; two places are neighbours when poses of theirs
are. In the abstract model a person is at one place and, each period, stays or
steps to a neighbouring place; what the sensors read of several people is each
sensor's combination (nearest, any) of what it reads of each alone. A sensor's
readings are state of its own (``<sensor>_reading``), taken at the sensor's own
period from the places before the step, as the twin's sensor takes them: whoever
reads them reads them a step later at the earliest. A reading only the sensor
itself reads (``AbstractCell.internal``: beams behind a restart interlock) stays
a formula of the places: the sensor's own module takes it at its period.

A grid only samples the floor: a feature thinner than its step may fall between
its points (an assumption stated with every result).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cellsim.verify.expressions import Thresholds, VerifyError
from cellsim.verify.model import AbstractCell, PersonRole, Pose, lookup, prism_name, set_of
from cellsim.verify.prism import Command, Enum, Module, Var


@dataclass
class Place:
    index: int
    reading: tuple
    """The read signals' codes here (own signals, then sensed), in ``Places.signals`` order."""
    poses: list[Pose]
    least: dict = field(default_factory=dict)
    """Each signal that cuts nothing (``SensedSignal.cuts``) -> (the pose of the place where it reads least, that
    value): the place's reading is that pose's."""


@dataclass
class PersonPlaces:
    role: PersonRole
    places: list[Place]
    neighbours: dict[int, set[int]]
    start: int
    variable: str
    signals: list[str]
    """The read signals a place's reading gives, in order."""
    every: int = 1
    """Steps between the person's updates (its own period over the step): it changes place only at those."""
    end: int | None = None
    """The place where its script leaves it at the run's end (``PersonRole.end``); None: not known."""
    crossings: dict = field(default_factory=dict, repr=False, compare=False)
    """:func:`crossing_periods` found so far, by (period, speed, exact): the model and each witness's check ask
    the same."""

    def at(self, place: int) -> Place:
        return self.places[place]

    def pace_departure(self, witness: list[dict], period: float, speed: float,
                       exact: bool = False) -> tuple[str, int] | None:
        """:func:`pace_departure` of this person (what a person's abstraction asks, without importing the floor)."""
        return pace_departure(self, witness, period, speed, exact)


@dataclass
class Places:
    people: list[PersonPlaces]
    poses_measured: int
    """Poses measured for this model (not those an earlier round's measured: ``cut_floor``)."""


SIDE_BY_SIDE_FROM = 400
"""Poses of one person from which they are measured in parts side by side, one process per core (a fork costs a
few milliseconds; a pose, about 0.1 ms for each sensor that reads it)."""


def cut_floor(cell: AbstractCell, measured: dict | None = None) -> Places:
    """Measure every person's poses and cut the floor into places (after round 1). ``measured``: (person, signal,
    pose) -> the value read there, by an earlier model of the same cell, kept and added to: a refinement's round
    measures only the poses no earlier round did (a pace's, none; a finer grid's, those between the coarser one's)."""
    from cellsim.verify.isolated import cores, side_by_side

    context = cell.cell.diagram.CreateDefaultContext()
    cell.cell.set_initial_state(context)
    for person in cell.people:
        person.stand(context, None)
    sensed = {f"{s.module}.{port}": (s, signal) for s in cell.sensors for port, signal in s.signals.items()}
    people, count = [], 0
    codes: dict = {}  # (signal, value) -> its code: the floor's poses read few values, each many times
    for person in cell.people:
        own = {f"{person.module}.{port}": fn for port, fn in person.own.items()}
        signals = [s for s in own if s in cell.reads] + [s for s in sensed if s in cell.reads]
        poses = list(dict.fromkeys([person.start, *([person.end] if person.end else []), *person.poses]))
        known = {} if measured is None else measured
        todo = [pose for pose in poses if any((person.module, s, pose) not in known for s in signals)]
        if person.refines:
            todo = _inherit(person, todo, signals, known,
                            frozenset(s for s in signals if s in sensed and not sensed[s][1].cuts))
        parts = cores() if len(todo) >= SIDE_BY_SIDE_FROM else 1
        size = max(1, -(-len(todo) // parts))
        works = [_measuring(context, person, todo[i:i + size], signals, own, sensed)
                 for i in range(0, len(todo), size)]
        for pose, values in zip(todo, (values for part in side_by_side(works) for values in part)):
            known.update(((person.module, s, pose), value) for s, value in zip(signals, values))
        cutting = [s for s in signals if s not in sensed or sensed[s][1].cuts]
        readings = [tuple(_coded(cell, codes, s, known[(person.module, s, pose)]) for s in cutting) for pose in poses]
        person.stand(context, None)
        count += len(todo)
        places = _places(cell, person, poses, readings, cutting)
        _least(cell, codes, places, [s for s in signals if s not in cutting], known)
        people.append(places)
    return Places(people, count)


def _least(cell: AbstractCell, codes: dict, person: PersonPlaces, signals: list[str], known: dict) -> None:
    """Each place of ``person`` reads, for each signal that cuts nothing, the least of its poses' values (the first
    pose reading it, in the place's order, is ``Place.least``'s), after the signals that cut it."""
    module = person.role.module
    for place in person.places:
        extra = []
        for s in signals:
            values = [known[(module, s, q)] for q in place.poses]
            at = min(range(len(values)), key=values.__getitem__)
            place.least[s] = (place.poses[at], values[at])
            extra.append(_coded(cell, codes, s, values[at]))
        place.reading = (*place.reading, *extra)
    person.signals = [*person.signals, *signals]


def _inherit(person: PersonRole, todo: list[Pose], signals: list[str], known: dict,
             loose: frozenset = frozenset()) -> list[Pose]:
    """Of the poses ``todo`` of a grid that halves a coarser one measured before (``person.refines``, m), those still
    to measure: a pose between points of the coarser grid (its corners there, at its heading and reach) that all read
    the same, every signal, reads as they do and is entered in ``known``; the others (where the coarser grid's
    readings change, or a corner was not measured: a reach's heading is its own) are returned. The finer grid is so
    measured where places meet, whose borders it finds more closely, and reads as the coarser one elsewhere: a
    feature thinner than the coarser step there may fall between its points, as it could before.

    ``loose``: the signals that cut nothing (``SensedSignal.cuts``: a lower bound of a distance, m), which decide
    nothing here. A pose not reaching out, whose body the corners' bodies translate, reads the most any corner's value
    less its distance to that corner allows (a distance moves no more than the body does: still a lower bound); a
    reaching pose (whose arm turns towards its point as it moves) is measured."""
    coarse, module = person.refines, person.module
    half = coarse / 2.0
    corners: dict = {}  # (x, y, yaw, reach) of a coarser grid's point -> its readings (None: not all measured)
    kept = [i for i, s in enumerate(signals) if s not in loose]

    def reading(x: float, y: float, yaw: float, reach) -> tuple | None:
        key = (x, y, yaw, reach)
        if key not in corners:
            corner = Pose(x, y, yaw, reach)
            values = tuple(known.get((module, s, corner), _UNKNOWN) for s in signals)
            corners[key] = None if _UNKNOWN in values else values
        return corners[key]

    def around(v: float) -> tuple[float, ...]:
        i = round(v / half)  # the finer grid's index: even on a line of the coarser grid
        return (v,) if i % 2 == 0 else (round((i - 1) * half, 6), round((i + 1) * half, 6))

    left = []
    for pose in todo:
        xs, ys = around(pose.x), around(pose.y)
        if len(xs) == len(ys) == 1 or (loose and pose.reach is not None):
            left.append(pose)  # a point of the coarser grid not measured (its own reading), or a reach to measure
            continue
        points = [(x, y) for x in xs for y in ys]
        readings = [reading(x, y, pose.yaw, pose.reach) for x, y in points]
        if None in readings or len({tuple(values[i] for i in kept) for values in readings}) != 1:
            left.append(pose)
            continue
        if loose:
            apart = [math.hypot(pose.x - x, pose.y - y) for x, y in points]
            values = [max(r[i] - d for r, d in zip(readings, apart)) if s in loose else readings[0][i]
                      for i, s in enumerate(signals)]
        else:
            values = readings[0]
        known.update(((module, s, pose), value) for s, value in zip(signals, values))
    return left


_UNKNOWN = object()
"""A reading not measured (:func:`_inherit`)."""


def _coded(cell: AbstractCell, codes: dict, signal: str, value) -> int:
    """``cell.code_of(signal, value)``, remembered in ``codes``."""
    key = (signal, value)
    code = codes.get(key)
    if code is None:
        code = codes[key] = cell.code_of(signal, value)
    return code


def _measuring(context, person: PersonRole, poses: list[Pose], signals: list[str], own: dict, sensed: dict):
    """The read signals' values at each of ``poses``, as work for ``side_by_side`` (each part in a process of its own,
    on its own copy of the context)."""

    def work(say) -> list[tuple]:
        readings = []
        for pose in poses:
            person.stand(context, pose)
            scans = {}  # a sensor's one measurement of this pose (SensorRole.measure), taken once

            def value(s: str):
                if s in own:
                    return own[s](pose)
                role, signal = sensed[s]
                if role.measure is None:
                    return signal.measure(context)
                if role.module not in scans:
                    scans[role.module] = role.measure(context)
                return signal.measure(scans[role.module])

            readings.append(tuple(value(s) for s in signals))
        return readings

    return work


def _places(cell, person: PersonRole, poses: list[Pose], readings: list[tuple], signals: list[str]) -> PersonPlaces:
    """The places: poses that read the same and touch (the same grid point, or neighbouring ones) joined. Poses at
    one point that read the same are one group (several headings and reaches): groups, not poses, are compared."""
    step = person.step
    cells: dict[tuple[int, int], dict[tuple, list[int]]] = {}  # grid point -> reading -> its poses there
    for i, pose in enumerate(poses):
        cells.setdefault((round(pose.x / step), round(pose.y / step)), {}).setdefault(readings[i], []).append(i)
    parent = list(range(len(poses)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for groups in cells.values():
        for members in groups.values():
            for i in members[1:]:
                parent[find(i)] = find(members[0])
    touching = []  # (group, group) at touching points: the same point (different readings) or grid neighbours
    for (cx, cy), groups in cells.items():
        here = list(groups.items())
        touching += [(a[1][0], b[1][0]) for k, a in enumerate(here) for b in here[k + 1:]]
        for dx, dy in itertools.product((-1, 0, 1), repeat=2):
            other = cells.get((cx + dx, cy + dy))
            if other is None or (dx, dy) <= (0, 0):
                continue
            for reading, members in groups.items():
                same = other.get(reading)
                if same is not None:
                    parent[find(members[0])] = find(same[0])
            touching += [(a[0], b[0]) for a in groups.values() for b in other.values()]
    roots = {}
    for i in range(len(poses)):
        roots.setdefault(find(i), []).append(i)
    order = sorted(roots.values(), key=lambda members: min(members))
    place_of = {}
    places = []
    for index, members in enumerate(order):
        for i in members:
            place_of[i] = index
        places.append(Place(index, readings[members[0]], [poses[i] for i in members]))
    neighbours: dict[int, set[int]] = {p.index: set() for p in places}
    for i, j in touching:
        a, b = place_of[i], place_of[j]
        if a != b:
            neighbours[a].add(b)
            neighbours[b].add(a)
    end = None if person.end is None else place_of[poses.index(person.end)]
    return PersonPlaces(person, places, neighbours, place_of[0], f"{person.module}_place", signals,
                        _person_every(cell, person), end)


def _person_every(cell: AbstractCell, person: PersonRole) -> int:
    """Steps between the model's takes of a person's place: its own period's, unless it could walk past a grid
    point in that time (two samples would then not be grid neighbours, and the floor steps only to neighbouring
    places): then at every step (more behaviours than the twin's, never fewer)."""
    every = cell.every(person.module)
    if person.top_speed is None or person.top_speed * every * cell.period > person.step:
        return 1
    return every


ENTERED_AT_START = -1
"""The place a person 'came from' in its starting place (it stands at its start pose)."""


def crossing_periods(person: PersonPlaces, period: float, speed: float, exact: bool = False) -> dict[tuple[int, int, int], int]:
    """(came from, place, going to) -> the least number of periods spent in the place, entering it from the first
    and leaving it to the third, at ``speed`` (m/s) at most (every triple with a bound above zero).

    The person enters at a pose of the place touching the one it came from (its start pose, in its starting place)
    and leaves from a pose touching the next: it has walked at least the distance d between those poses less a grid
    step at either end (it changes place somewhere between two touching poses). The model samples it once a period:
    seen in the place at samples e .. l - 1 and in the next at l, it may have crossed in just under l - e + 1
    periods (entering right after sample e - 1), so it is seen there for at least ceil(d / (speed * period)) - 1
    samples; from its start pose (there at sample 0) for at least ceil(d / (speed * period)).

    ``exact``: without the grid steps' slack, as if each place's border lay on its touching poses: no bound (it may
    claim more than a walk takes), but where it says more than the bound does, a finer grid would tell."""
    key = (period, speed, exact)
    found = person.crossings.get(key)
    if found is None:
        found = person.crossings[key] = _crossing_periods(person, period, speed, exact)
    return found


def _crossing_periods(person: PersonPlaces, period: float, speed: float, exact: bool) -> dict[tuple[int, int, int], int]:
    """:func:`crossing_periods`, computed: each place's borders found in one pass over its poses, each pair of
    borders' least distance in one numpy expression."""
    step = person.role.step
    cell_of: dict[tuple[int, int], set[int]] = {}
    for place in person.places:
        for pose in place.poses:
            cell_of.setdefault((round(pose.x / step), round(pose.y / step)), set()).add(place.index)
    around = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]

    def borders(place: Place) -> dict[int, np.ndarray]:
        """Each neighbouring place -> the points of ``place`` touching it (a grid neighbour or the same point)."""
        found: dict[int, dict] = {}
        for pose in place.poses:
            cx, cy = round(pose.x / step), round(pose.y / step)
            touching = set().union(*(cell_of.get((cx + dx, cy + dy), ()) for dx, dy in around))
            for other in touching:
                found.setdefault(other, {})[(pose.x, pose.y)] = None
        return {other: np.array(list(points), float) for other, points in found.items()}

    need = {}
    for place in person.places:
        touching = borders(place)
        exits = {b: touching.get(b, np.empty((0, 2))) for b in person.neighbours[place.index]}
        entries = dict(exits)  # a neighbour's border is where one enters from it as well as where one leaves to it
        if place.index == person.start:
            entries[ENTERED_AT_START] = np.array([[person.role.start.x, person.role.start.y]], float)
        for a, ins in entries.items():
            for b, outs in exits.items():
                if a == b or not len(ins) or not len(outs):
                    continue
                from_start = a == ENTERED_AT_START
                slack = 0.0 if exact else (step if from_start else 2 * step)
                distance = _least_distance(ins, outs) - slack
                crossing = math.ceil(distance / (speed * period) - 1e-9) if distance > 0 else 0
                periods = crossing if from_start else crossing - 1
                if periods > 1:  # one period is what any step takes
                    need[(a, place.index, b)] = periods
    return need


def _least_distance(ins, outs) -> float:
    """The least distance (m) between any of the points ``ins`` and any of ``outs`` ((n, 2) arrays), in blocks of a
    few million pairs."""
    best = math.inf
    rows = max(1, 4_000_000 // len(outs))
    for first in range(0, len(ins), rows):
        block = ins[first:first + rows]
        d2 = ((block[:, None, :] - outs[None, :, :]) ** 2).sum(axis=2)
        best = min(best, float(d2.min()))
    return math.sqrt(best)


def pace_departure(person: PersonPlaces, witness: list[dict], period: float, speed: float,
                   exact: bool = False) -> tuple[str, int] | None:
    """Where a witness (a state a step of ``period`` s) has ``person`` cross a place faster than ``speed`` allows
    (the first such crossing): which variable, at which period, and why, and the witness's step where the person
    leaves the place too soon (the first state the cell cannot be in); None if it never does (``exact``: see
    :func:`crossing_periods`). The person is sampled at its own period (``person.every`` steps)."""
    every = person.every
    need = crossing_periods(person, period * every, speed, exact)
    var = person.variable
    came, entered, here = ENTERED_AT_START, 0, None
    for k, state in enumerate(witness):
        place = state.get(var)
        if place is None:
            return None
        if here is None:
            here = place
            continue
        if place != here:
            least, took = need.get((came, here, place), 1), -(-(k - entered) // every)  # (its own periods)
            if took < least:
                own = "" if every == 1 else f" of its {period * every:g} s"
                return (f"{var} crosses place {here} (from {'its start' if came == ENTERED_AT_START else f'place {came}'} "
                        f"to place {place}) in {took} period(s){own} at {entered * period:g}-{k * period:g} s; at "
                        f"{speed:.3g} m/s that takes at least {least} ({least * period * every:g} s)", k)
            came, entered, here = here, k, place
    return None


def press_variable(module: str, port: str) -> str:
    """The PRISM variable saying whether a person presses a button this period."""
    return f"{module}_pressing_{port}"


def build_floor(cell: AbstractCell, places: Places) -> None:
    """Each person's module (its place, the buttons it may press) and every floor signal's formula."""
    sensed = {f"{s.module}.{port}": signal for s in cell.sensors for port, signal in s.signals.items()}
    per_signal: dict[str, list[str]] = {}
    for person in places.people:
        role, var = person.role, person.variable
        n = len(person.places)
        variables = [Var(var, 0, n - 1, person.start)]
        presses = {}
        for port, spot in role.buttons.items():
            press_var = press_variable(role.module, port)
            near = [p.index for p in person.places if any(math.hypot(q.x - spot[0], q.y - spot[1]) <= role.step for q in p.poses)]
            if not near:
                raise VerifyError(f"{role.module}: no place of the floor holds the spot {list(spot)} where it presses {port}")
            presses[press_var] = set_of(var, near) if n > 1 else "true"
            variables.append(Var(press_var, boolean=True))
            cell.define(f"{role.module}.{port}", f"({press_var} ? 1 : 0)", Enum(("0", "1")))
        commands = _walks(cell, person, _paced(cell, person, variables), presses)
        how = (f"each period it stays or steps to a neighbour, crossing a place no faster than {role.max_speed:.3g} m/s"
               if role.max_speed else "each period it stays or steps to a neighbour")
        cell.add(Module(f"{role.module}_floor", variables, commands, comment=f"{role.module}: one of {n} places of the floor; {how}"),
                 every=person.every, owner=role.module)  # (at its own period where the grid allows it)
        for k, signal in enumerate(person.signals):
            table = {place.index: place.reading[k] for place in person.places}
            encoding = cell.encoding(signal)
            if n == 1:  # (Storm folds a variable of one value into a constant, then knows it nowhere: read none)
                expr = str(table[0]) if encoding is not bool else ("true" if table[0] else "false")
            else:
                expr = lookup(var, table, -1) if encoding is not bool else set_of(var, [i for i, v in table.items() if v])
            if signal in sensed:
                name = f"{signal}.of_{role.module}"
                per_signal.setdefault(signal, []).append(cell.define(name, expr, encoding))
            else:
                cell.define(signal, expr, encoding)
    readings: dict[str, list[tuple[str, str]]] = {}  # sensor -> (its signal, what it reads of the places now)
    for signal, parts in per_signal.items():
        if sensed[signal].combine is None:  # each person's alone: its module reads the .of_<person> formulas
            continue
        expr = _combine(cell, signal, parts, sensed[signal])
        if signal in cell.internal:
            cell.define(signal, expr, cell.encoding(signal))
        else:
            readings.setdefault(signal.split(".", 1)[0], []).append((signal, expr))
    for sensor, signals in readings.items():
        _sampled(cell, sensor, signals)
    cell.assume(f"the floor is sampled on a grid ({', '.join(_grid_words(p) for p in places.people)}); "
                "a feature thinner than a step may fall between its points")


def _grid_words(person: PersonPlaces) -> str:
    """How a person's grid is sampled, in words (the floor's assumption)."""
    role = person.role
    grid = f"{role.step:g} m" if not role.refines else (f"{role.step:g} m where the {role.refines:g} m grid's readings "
                                                        f"change, elsewhere read as its points around")
    return f"{role.module}: {grid}, {len(person.places)} places"


def _walks(cell: AbstractCell, person: PersonPlaces, paced, presses: dict[str, str]) -> list[Command]:
    """A person's commands: stay, or take the ``d``-th step (``d`` up to the most neighbours a place has), each with
    every choice of the buttons it may press where it stands (``presses``: variable -> where).

    A step is one command per direction, not per pair of places: the ``d``-th neighbour of each place is a formula
    (``<var>_to<d>``, -1 where a place has fewer), and so is what its pace asks of that step (``<var>_may<d>``).
    The choices in each state are the same as one command per pair would give; Storm, which tries every command's
    guard in every state it builds state by state, tries a few dozen instead of a few hundred (the machine-tending
    cell's 83 places: 688 commands), and builds that cell's witness model in two thirds of the time."""
    var = person.variable
    moves = {p.index: sorted(person.neighbours[p.index] - {p.index}) for p in person.places}
    steps = [("true", paced.stay)]
    for d in range(max((len(there) for there in moves.values()), default=0)):
        _formula(cell, f"{var}_to{d}", lookup(var, {p: there[d] for p, there in moves.items() if len(there) > d}, -1))
        may = {p: paced.step_guard(p, there[d]) for p, there in moves.items() if len(there) > d}
        guard = f"{var}_to{d}>=0"
        if any(g != "true" for g in may.values()):
            _formula(cell, f"{var}_may{d}", _case(var, may))
            guard += f" & {var}_may{d}"
        steps.append((guard, {var: f"{var}_to{d}", **paced.step}))
    commands = []
    for guard, update in steps:
        for pressed in itertools.product((False, True), repeat=len(presses)):
            chosen, where = dict(update), [guard] if guard != "true" else []
            for (press_var, spot), on in zip(presses.items(), pressed):
                chosen[press_var] = "true" if on else "false"
                if on:
                    where.append(spot)
            commands.append(Command(" & ".join(where) or "true", (("1", chosen),)))
    return commands


def _formula(cell: AbstractCell, name: str, expr: str) -> None:
    """A formula of the floor's own (no signal's), under a name nothing else has taken."""
    if name in cell.formulas:
        raise VerifyError(f"the abstract model names two formulas {name}: rename the module whose name makes it")
    cell.formulas[name] = expr


def _case(var: str, cases: dict[int, str]) -> str:
    """A condition that is ``cases[k]`` where ``var`` is ``k`` (every value of ``var`` that matters is a key)."""
    groups: dict[str, list[int]] = {}
    for key, condition in sorted(cases.items()):
        groups.setdefault(condition, []).append(key)
    out = "true"
    for condition, keys in sorted(groups.items(), key=lambda item: item[1][0], reverse=True):
        if condition != "true":
            out = f"({set_of(var, keys)} ? ({condition}) : {out})"
    return out


@dataclass(frozen=True)
class _Pace:
    """What a person's pace asks of its moves: ``stay``, the update of a period it stays; ``step``, that of a step
    (the same for every step); ``step_guard(here, there)``, the condition for the step from ``here`` to ``there``
    ("true": none)."""

    stay: dict
    step: dict
    step_guard: Callable[[int, int], str]


def _paced(cell: AbstractCell, person: PersonPlaces, variables: list) -> _Pace:
    """The guards and updates that keep ``person`` from crossing a place faster than its ``max_speed`` (none without
    one): where it came from and how many periods it has stayed, counted, and each step's condition on them."""
    speed = person.role.max_speed
    if not speed:
        return _Pace({}, {}, lambda here, there: "true")
    need = crossing_periods(person, cell.period * person.every, speed)  # in its own periods
    var, came, dwell = person.variable, f"{person.variable}_from", f"{person.variable}_dwell"
    most = max(need.values(), default=1)
    variables += [Var(came, ENTERED_AT_START, len(person.places) - 1, ENTERED_AT_START), Var(dwell, 0, most, 0)]

    slow: dict[tuple[int, int], list[tuple[int, int]]] = {}  # (here, there) -> [(came from, periods the crossing takes)]
    for (a, here, there), k in sorted(need.items()):
        slow.setdefault((here, there), []).append((a, k))

    def step_guard(here: int, there: int) -> str:
        # from where it came: the periods the crossing takes (dwell counts the periods after the first)
        return " & ".join(f"!({came}={a} & {dwell}<{k - 1})" for a, k in slow.get((here, there), ())) or "true"

    # staying: one more period here, counted up to the longest crossing any step from here asks of a person who came
    # from where this one did: past it, every guard reads the same, so more counting would only make states that
    # behave alike (the welding cell's paced model: 391,404 states to 80,166, the same value for every property)
    enough: dict[tuple[int, int], int] = {}  # (here, came from) -> the most any step's guard counts to
    for (a, here, _), k in need.items():
        enough[(here, a)] = max(enough.get((here, a), 0), k - 1)
    cap = "0"
    for (here, a), most_here in sorted(enough.items(), reverse=True):
        cap = f"(({var}={here} & {came}={a}) ? {most_here} : {cap})"
    _formula(cell, f"{dwell}_enough", cap)
    # stepping: from here, none yet there
    return _Pace({dwell: f"min({dwell}+1, {dwell}_enough)"}, {came: var, dwell: "0"}, step_guard)


def _combine(cell: AbstractCell, signal: str, parts: list[str], sensed) -> str:
    """What a sensor reads of all the people: its combination of what it reads of each alone (an expression)."""
    encoding = cell.encoding(signal)
    if len(parts) == 1:
        return parts[0]
    if encoding is bool:
        combined = sensed.combine([False, True])
        if combined is not True:
            raise VerifyError(f"{signal}: only 'any of them' combines booleans")
        return "(" + " | ".join(parts) + ")"
    codes = range(encoding.regions) if isinstance(encoding, Thresholds) else range(len(encoding.values))
    cases = []
    for combo in itertools.product(codes, repeat=len(parts)):
        value = sensed.combine([_value(encoding, c) for c in combo])
        cases.append((combo, _code_of(encoding, value)))
    out = "-1"
    for combo, code in reversed(cases):
        guard = " & ".join(f"{p}={c}" for p, c in zip(parts, combo))
        out = f"({guard} ? {code} : {out})"
    return out


def _sampled(cell: AbstractCell, sensor: str, signals: list[tuple[str, str]]) -> None:
    """The sensor's readings as state (``<signal>_read``), each taken from ``expr`` at the sensor's own period, from
    the reading the twin's sensor starts with."""
    variables, update = [], {}
    for signal, expr in signals:
        encoding, var = cell.encoding(signal), prism_name(signal) + "_read"
        if encoding is bool:
            variables.append(Var(var, boolean=True, init=bool(cell.initial_code(signal))))
        else:
            values = encoding.regions if isinstance(encoding, Thresholds) else len(encoding.values)
            variables.append(Var(var, 0, values - 1, cell.initial_code(signal),
                                 enum=encoding if isinstance(encoding, Enum) else None))
        update[var] = expr
    every = cell.every(sensor)
    cell.add(Module(f"{sensor}_reading", variables, [Command("true", (("1", update),))],
                    comment=f"{sensor}: what it reads of the people, taken every {every} step(s) (its own period)"),
             every=every, owner=sensor)
    for (signal, _), var in zip(signals, variables):
        cell.define(signal, var.name, cell.encoding(signal))


def _value(encoding, code: int):
    if isinstance(encoding, Thresholds):
        values = encoding.values
        if code % 2:
            return values[code // 2]
        i = code // 2
        low = values[i - 1] if i > 0 else (values[0] - 1.0 if values else -1.0)
        high = values[i] if i < len(values) else (values[-1] + 1.0 if values else 1.0)
        return (low + high) / 2
    return encoding.values[code]


def _code_of(encoding, value) -> int:
    if isinstance(encoding, Thresholds):
        return encoding.region_of(float(value))
    return encoding.code(value.value if hasattr(value, "value") else value)
