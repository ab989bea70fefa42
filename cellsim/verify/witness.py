"""A violated property's witness, replayed on the twin: confirmed or refuted.

The witness is a path of the abstract model (one state per period). Each
person's places along it become a walk in the person kind's own config (its
``PersonRole.walk``): one stop per place it enters, at the place's inner pose
nearest the last stop (so the walk goes no further than it must), arrived at
when the path enters the place and left when it leaves, the last held to the
end of the run. The walk is written as a scenario whose ``base:`` is the verified one,
simulated, and checked with the scenario's own conditions.

The abstract people walk at any pace and the abstract robot takes its moves in
any time: the twin walks at the person's speed and moves the arm at its own, so
the walk is tried as written and then started later (``SHIFTS``), the same
walk at other moments of the robot's cycle. The twin *confirms* the witness when
one of these runs shows the same violation (the condition fails, or the hazard
reaches its mishap phase), and *refutes* it otherwise: the abstraction is then
too coarse there, a finding about the model, not about the cell.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from cellsim.verify.floor import press_variable
from cellsim.verify.storm import Checked

SHIFTS = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0)
"""Seconds the witness walk is started later, in the order tried."""
SETTLE = 8.0
"""Seconds the run goes on after the witness ends."""


@dataclass
class Replay:
    """What the twin said of one witness."""

    confirmed: bool
    scenarios: list[Path] = field(default_factory=list)
    runs: list[Path] = field(default_factory=list)
    shift: float | None = None
    """The shift (s) of the run that confirmed it."""
    violated: list[str] = field(default_factory=list)
    """The conditions the confirming (else the last) run violated."""
    lag: str = ""
    """How much longer the twin takes to walk the witness than the witness itself does, and where most of it comes
    from (:func:`lag`), in words; empty where it keeps the witness's time."""
    seen: list = field(default_factory=list, repr=False, compare=False)
    """Every run made, in order: (shift, scenario, run folder, the conditions it violated)."""


class _Replace(dict):
    """A mapping written with the ``!replace`` tag: it replaces the base's instead of merging."""


def _replace(dumper, data):
    return dumper.represent_mapping("!replace", dict(data), flow_style=False)


class _Dumper(yaml.SafeDumper):
    pass


_Dumper.add_representer(_Replace, _replace)


def walks(model, checked: Checked, shift: float) -> tuple[dict, float]:
    """Each person's config keys for the witness walk, and the run's duration (s).

    The abstract people step from place to place in a period; the twin's walk at their
    speed. The witness's clock is stretched to fit: step k happens at ``clock[k]``, at least a
    period after step k - 1 and, when a person enters a new place there, at least its walk from
    the last stop later. So every person's stops keep their order against everyone else's."""
    people, clock, _ = _timed(model, checked, shift)
    period, path = model.cell.period, checked.witness
    end = clock[-1] + period
    entities = {}
    for person, runs in people:
        role = person.role
        buttons = {port: press_variable(role.module, port) for port in role.buttons}
        stops, presses = [], {}
        for i, (place, first, last, pose) in enumerate(runs):
            if i == 0 and place == person.start and pose == role.start:
                continue  # where it starts (unless the run ends in its starting place, at its last stop)
            pressed = [port for port, var in buttons.items() if any(path[s].get(var) for s in range(first, last + 1))]
            if pressed:
                presses[len(stops)] = pressed[0]
            stops.append((pose, clock[first], clock[last] + period))
        if not stops:
            stops = [(role.start, 0.0, 0.0)]
        stops[-1] = (stops[-1][0], stops[-1][1], end + SETTLE)
        entities[role.module] = role.walk(role.start, stops, presses)
    return entities, end + SETTLE


LAG = 0.1
"""Seconds by which the twin's walk of a witness may outlast the witness before :func:`lag` says so."""


def lag(model, checked: Checked) -> str:
    """In words, how much longer the twin takes to walk ``checked``'s witness than the witness takes (its clock
    stretched so each person walks from stop to stop at their speed, :func:`walks`), and the leg that adds the most;
    empty where that is under :data:`LAG`. The model bounds a person's pace place by place (the least distance across
    each place it crosses), and the replay walks from a pose inside each place to one inside the next: where those
    are farther apart than the witness's steps allow, the twin meets the robot's cycle at other moments than the
    witness did, which may be why it does not show the violation."""
    _, clock, legs = _timed(model, checked, 0.0)
    period = model.cell.period
    witness_time = (len(checked.witness) - 1) * period
    extra = clock[-1] - witness_time
    if extra < LAG or not legs:
        return ""
    module, a, b, took, step = max(legs, key=lambda leg: leg[3])
    return (f"the twin takes {clock[-1]:.3g} s to walk the witness's {witness_time:.3g} s: {module} walks from "
            f"({a.x:.2f}, {a.y:.2f}) to ({b.x:.2f}, {b.y:.2f}) in {took:.3g} s, one {period:g} s step in the witness "
            f"(at {step * period:g} s), so the twin meets the rest of the cell at other moments than the witness did "
            "(the model bounds a person's pace place by place, and the replay walks from a pose inside each place to "
            "one inside the next)")


def _timed(model, checked: Checked, shift: float) -> tuple[list, list[float], list]:
    """(each person with its runs of places [place, first step, last step, pose]; the clock of the witness's steps,
    stretched so each person walks from stop to stop at their speed, from ``shift``; each leg that stretched it:
    (person, from pose, to pose, seconds its walk takes, the step it ends at))."""
    places = model.cell.places
    period = model.cell.period
    path = checked.witness
    people = []
    for person in places.people:
        runs = []  # [place, first step, last step, pose]
        for step, state in enumerate(path):
            # a person outside the property's cone of influence (cellsim.verify.cone) is not in the witness: what
            # they do cannot change it, so they stay where they start
            place = state.get(person.variable, person.start)
            if runs and runs[-1][0] == place:
                runs[-1][2] = step
            else:
                here = runs[-1][3] if runs else person.role.start
                pose = person.role.start if not runs and place == person.start else _stand_in(person, place, here)
                runs.append([place, step, step, pose])
        if checked.prop.final and person.end is not None and runs[-1][0] == person.end:
            runs[-1][3] = person.role.end  # a run that ends as the person's script does: at its very last stop
        elif path:
            runs[-1][3] = _last_stop(model, checked, person, runs[-1][0], path[-1]) or runs[-1][3]
        people.append((person, runs))
    clock, legs = [shift], []
    for step in range(1, len(path)):
        at = clock[-1] + period
        for person, runs in people:
            for previous, run in zip(runs, runs[1:]):
                if run[1] == step:
                    took = person.role.travel(previous[3], run[3])
                    if took > period:
                        legs.append((person.role.module, previous[3], run[3], took, step))
                    at = max(at, clock[-1] + took)
        clock.append(at)
    return people, clock, legs


def walk_key(model, checked: Checked) -> tuple:
    """What decides the walk a witness is replayed as, beyond its path: whether the property is a ``Final`` one (its
    walk ends at the script's end) and which modules' abstractions choose where it stops (``witness_pose``). Two
    witnesses with equal keys are written as the same scenario."""
    choosers = tuple(i for i, part in enumerate(getattr(model, "parts", ()))
                     if getattr(part, "chooses_pose_for", lambda prop: False)(checked.prop))
    return checked.witness, bool(getattr(checked.prop, "final", False)), choosers


def _last_stop(model, checked: Checked, person, place: int, state: dict):
    """Where a module's abstraction would have the person stand at the witness's last place, for the witness's
    last ``state`` (its ``witness_pose``: where a contact's bound is least), else None."""
    for part in getattr(model, "parts", ()):
        choose = getattr(part, "witness_pose", None)
        pose = choose(model.cell, checked.prop, person, place, state) if choose is not None else None
        if pose is not None:
            return pose
    return None


def _stand_in(person, place: int, here):
    """Where in the place the walk stops: the pose nearest ``here`` (the last stop) among the place's
    inner poses (each of whose grid neighbours, at its heading, is in the place too), else among all of
    its poses; with the arm down where the place allows it, else reaching."""
    poses = person.at(place).poses
    poses = [p for p in poses if p.reach is None] or poses
    step = person.role.step
    spots = {(round(p.x / step), round(p.y / step), round(p.yaw, 3)) for p in poses}
    inner = [p for p in poses if all((round(p.x / step) + dx, round(p.y / step) + dy, round(p.yaw, 3)) in spots
                                     for dx in (-1, 0, 1) for dy in (-1, 0, 1))]
    return min(inner or poses, key=lambda p: (math.hypot(p.x - here.x, p.y - here.y), p.yaw))


def write_scenario(model, checked: Checked, out: Path, shift: float) -> Path:
    """The witness walk as a scenario over the verified one (``base:``), under ``out``."""
    sf = model.cell.sf
    entities, duration = walks(model, checked, shift)
    for config in entities.values():
        config["waypoints"] = _Replace(config["waypoints"])
    name = "".join(c if c.isalnum() else "_" for c in checked.prop.name)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}{'' if not shift else f'_later_{shift:g}s'.replace('.', '_')}.yaml"
    document = {
        "base": os.path.relpath(sf.source, out),
        "name": f"{sf.scenario.name}_{name}_witness",
        "description": f"Witness of '{checked.prop.name}' ({checked.prop.description}) found by cellsim verify"
                       + (f", started {shift:g} s later" if shift else ""),
        "duration": round(duration, 3),
        "entities": entities,
        # the base's configuration points and campaign name the walk this one replaces
        "configuration_points": _Replace(),
        "campaign": _Replace(),
    }
    _merge_missing(document, _overrides(sf))
    header = (f"# Witness of {checked.prop.name}, written by `cellsim verify` from a shortest path of the abstract model\n"
              f"# ({len(checked.witness)} periods of {model.cell.period:g} s). Simulate it with `cellsim simulate {path.name}`.\n")
    text = header + yaml.dump(document, Dumper=_Dumper, sort_keys=False, default_flow_style=None, width=120)
    from cellsim.atomic import write_text

    write_text(path, text)
    return path


def _overrides(sf) -> dict:
    """The verified scenario's ``--set`` overrides as keys of a scenario over its base: each value as it
    was verified (a list is written whole, as the merge replaces lists)."""
    from cellsim.config.typed_yaml import _parse_override, to_data
    from cellsim.scenario import _shortcut

    data = to_data(sf.scenario)
    out: dict = {}
    for assignment in sf.overrides:
        keys, _, _ = _parse_override(sf.scenario, assignment, _shortcut(sf.scenario))
        keys = [to_data(k) for k in keys]
        if any(isinstance(k, int) for k in keys):
            keys = keys[:next(i for i, k in enumerate(keys) if isinstance(k, int))]
        value, target = data, out
        for key in keys:
            value = value[key]
        for key in keys[:-1]:
            target = target.setdefault(key, {})
        target[keys[-1]] = value
    return out


def _merge_missing(document: dict, extra: dict) -> None:
    """Add ``extra``'s keys to ``document`` where the document (the witness) says nothing of them."""
    for key, value in extra.items():
        mine = document.get(key)
        if key not in document:
            document[key] = value
        elif isinstance(mine, dict) and isinstance(value, dict) and not isinstance(mine, _Replace):
            _merge_missing(mine, value)


def replay(model, checked: Checked, out: Path, on_stage=None, at_once: int | None = None,
           same: Replay | None = None) -> Replay:
    """Write, simulate and check the witness (then later starts of it) until the twin shows the violation: the
    starts in ``SHIFTS`` order, ``at_once`` of them side by side (default: one per core), the first in that order
    that shows it confirming the witness (a later one run beside it is not counted; its run stays in its
    folder). ``same``: the replay of another condition's witness, the very same path: its runs are judged for this
    condition too, not run again, and only the starts it did not run are run."""
    from cellsim.verify.isolated import cores, side_by_side

    say = on_stage or (lambda text: None)
    outcome = Replay(False, lag=lag(model, checked))
    done = set()
    if same is not None and checked.prop.condition is not None:
        for shift, scenario, run, violated in same.seen:
            outcome.seen.append((shift, scenario, run, violated))
            outcome.scenarios.append(scenario)
            outcome.runs.append(run)
            outcome.violated = violated
            done.add(shift)
            if checked.prop.condition in violated:
                outcome.confirmed, outcome.shift = True, shift
                return outcome
    at_once = at_once or cores()
    left = [shift for shift in SHIFTS if shift not in done]
    for first in range(0, len(left), at_once):
        batch = []
        for shift in left[first:first + at_once]:
            scenario = write_scenario(model, checked, out, shift)
            say(f"twin: simulating {scenario.name}")
            batch.append((shift, scenario, out / "runs" / scenario.stem))
        seen = side_by_side([_twin_run(checked, scenario, run) for _, scenario, run in batch], at_once)
        for (shift, scenario, run), (violated, shows) in zip(batch, seen):
            outcome.seen.append((shift, scenario, run, violated))
            outcome.scenarios.append(scenario)
            outcome.runs.append(run)
            outcome.violated = violated
            if shows:
                outcome.confirmed, outcome.shift = True, shift
                return outcome
    return outcome


def _twin_run(checked: Checked, scenario: Path, run: Path):
    """The twin's run of one witness scenario, as work for :func:`cellsim.verify.isolated.side_by_side`: (the
    conditions it violated, whether it shows the property's violation)."""

    def work(say):
        from cellsim.scenario import load_scenario
        from cellsim.validation.check import simulate_and_check
        from cellsim.validation.verdict import Verdict

        sf = load_scenario(scenario)
        done = simulate_and_check(sf, run, seed=sf.scenario.seed, overwrite=True)
        result = done.checked.result if done.checked else None
        violated = [n for n, v in result.verdicts.items() if v.status is Verdict.VIOLATED] if result else []
        return violated, _shows(checked, done.summary, violated)

    return work


def _shows(checked: Checked, summary, violated: list[str]) -> bool:
    """Whether the twin's run shows what the model checker found: the condition violated, or the hazard's
    mishap reached (as the run's summary counts it, ``cellsim.hazards``)."""
    prop = checked.prop
    if prop.condition is not None:
        return prop.condition in violated
    if prop.hazard is not None:
        counts = summary.hazards.get(prop.hazard[0])
        return counts is not None and counts.mishaps > 0
    return False
