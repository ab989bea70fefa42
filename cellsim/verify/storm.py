"""Storm (through stormpy) builds the abstract model and checks its properties.

The program is written to a file (Storm's parser reads files) and built with
every variable's valuation kept, so a witness path reads back in the cell's
words. A safety property is ``Pmax=? [ F "bad" ]``: the largest probability,
over all resolutions of the nondeterminism, of reaching its bad states. Its
witness is a shortest path (in periods) from the initial state to a bad state,
taking at each step, of the successors one period nearer, one where the fewest
people change place; when the largest
probability is above 0 some scheduler follows it. For a bounded response the
shortest path to a *sustained* violation (the whole window missed) is preferred
when there is one.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

from cellsim.verify.expressions import VerifyError
from cellsim.verify.model import Property
from cellsim.verify.prism import PERIODS


@dataclass
class Checked:
    prop: Property
    value: float | bool | None
    seconds: float
    holds: bool | None
    """A safety property: value == 0; a boolean PCTL query: its value; a numeric one: None."""
    witness: list[dict] | None = None
    """The valuations of the states along a shortest path to a bad state (a violated safety property)."""
    fair: bool | None = None
    """A liveness condition whose stronger response failed: whether it holds under fairness
    (:func:`always_answerable`, and not :func:`owed_at_the_end`); None when not asked."""
    owed_at_end: bool = False
    """A liveness condition whose response can always still come, but not while the people stand where their
    scripts leave them, from a state reachable with it owed (:func:`owed_at_the_end`): a run may end owing it."""
    witness_from: str = ""
    """Where the witness came from when not the property's own model: the people a smaller model held at their
    start (``cellsim.verify.run``: the whole cell too large to make sparse)."""
    deferred: bool = False
    """Violated, its witness not built: a refinement took up another property's witness in the same round, and the
    refined model checks this one again (``verify(..., enough=...)``); never in a round's final result."""
    left_out: tuple[str, ...] = ()
    """The modules outside the property's cone of influence (:mod:`cellsim.verify.cone`), when its witness came
    from its cone: the witness's states hold none of their variables (a person left out stays at their start)."""


@dataclass
class ModelStats:
    states: int
    transitions: int
    choices: int
    build_seconds: float
    parse_seconds: float
    deadlocks: int = 0
    symbolic: bool = False
    """A model built as decision diagrams; the whole cell's in a verification: some violated property's own model had
    too many transitions to make sparse (its witness sought with people held)."""
    made_sparse: bool = False
    """(the whole cell's in a verification) some violated property's own model was built as decision diagrams and made
    sparse (:func:`to_sparse`), for its witness."""
    by_state: bool = False
    """(the whole cell's in a verification) some violated property's own model was built state by state."""


def _quiet():
    import stormpy

    try:
        stormpy.developer.set_log_level(stormpy.developer.LogLevel.OFF)  # noqa - not in every build
    except Exception:  # noqa: BLE001
        pass
    return stormpy


EXPLICIT_LIMIT = 20_000_000
"""Transitions above which the model is checked symbolically (decision diagrams) rather than built
state by state: 514 million transitions (the palletising cell) would not fit in memory."""


def _parse(program_path: Path):
    stormpy = _quiet()
    try:
        return stormpy.parse_prism_program(str(program_path))
    except Exception as e:  # noqa: BLE001 - Storm's parser errors are our translation's bugs, said plainly
        raise VerifyError(f"Storm cannot read the abstract model ({program_path}): {' '.join(str(e).split())[:400]}") from None


def _refuse_deadlocks(deadlocks: int, program_path: Path) -> None:
    if deadlocks:
        raise VerifyError(f"the abstract model has {deadlocks if deadlocks > 0 else 'some'} state(s) where some "
                          f"module cannot step (a bug of a kind's abstraction; the model: {program_path})")


def build(program_path: Path):
    """Parse and build the model state by state; returns (stormpy program, model, stats).

    A state where some module has no command enabled is a bug of that module's abstraction:
    Storm would quietly give it a self-loop and so drop every behaviour after it (a "holds"
    that is not). It is refused."""
    stormpy = _quiet()
    start = time.perf_counter()
    program = _parse(program_path)
    parsed = time.perf_counter()
    options = stormpy.BuilderOptions(build_full=True)
    options.set_build_state_valuations(True)
    model = stormpy.build_model(program, options=options)
    built = time.perf_counter()
    deadlocks = model.labeling.get_states("deadlock").get_number_of_set_bits() if model.labeling.contains_label("deadlock") else 0
    stats = ModelStats(model.nr_states, model.nr_transitions, model.nr_choices, built - parsed, parsed - start, deadlocks)
    _refuse_deadlocks(deadlocks, program_path)
    return program, model, stats


DD_MEMORY = 2048
"""MB the decision diagrams' tables may take (Sylvan's cap; Storm's default is 4096): the palletising cell's
2.4 million states build as fast in 2048 as in 4096 and 40 % slower in 1024; a smaller model never takes it all."""


def build_symbolic(program_path: Path, memory: int = DD_MEMORY):
    """Parse and build the model as decision diagrams (Storm's dd engine, Sylvan, its tables capped at ``memory``
    MB); returns (stormpy program, model, stats). Far larger models fit; a witness is read from its sparse form
    (:func:`to_sparse`). Deadlocks are refused as in ``build``."""
    stormpy = _quiet()
    from stormpy.environments import Environment

    start = time.perf_counter()
    program = _parse(program_path).substitute_formulas()  # the dd engine's labels read variables only
    parsed = time.perf_counter()
    environment = Environment()
    environment.dd().sylvan().maximal_memory = memory
    model = stormpy.build_symbolic_model(program, environment=environment)
    built = time.perf_counter()
    stats = ModelStats(model.nr_states, model.nr_transitions, model.nr_choices, built - parsed, parsed - start,
                       symbolic=True)
    deadlocked = _initial_value(stormpy, model, stormpy.parse_properties('Pmax=? [ F "deadlock" ]', program)[0])
    _refuse_deadlocks(-1 if deadlocked > 0 else 0, program_path)
    return program, model, stats


VALUE_BIT = "val_{name}_{bit}"
"""A label of the states where bit ``bit`` of a variable's value (its offset from the lowest, or the boolean) is 1."""


def valuation_labels(variables: dict) -> str:
    """PRISM labels carrying every variable's value bit by bit (``VALUE_BIT``), for :func:`to_sparse`: a model built
    as decision diagrams and made sparse keeps its labels but not its states' valuations."""
    lines = []
    for var in variables.values():
        for bit in range(_bits(var)):
            carries = var.name if var.boolean else f"mod({var.name} - ({var.low}), {2 ** (bit + 1)}) >= {2 ** bit}"
            lines.append(f'label "{VALUE_BIT.format(name=var.name, bit=bit)}" = {carries};')
    return "\n".join(lines) + "\n"


def _bits(var) -> int:
    """How many bits carry a variable's value (a boolean: one)."""
    return 1 if var.boolean else max(1, (var.high - var.low).bit_length())


class LabelledValuations:
    """The states' valuations of a sparse model made from decision diagrams, read from :func:`valuation_labels`."""

    def __init__(self, model, variables: dict):
        self._bits = {name: [model.labeling.get_states(VALUE_BIT.format(name=name, bit=bit)) for bit in range(_bits(var))]
                      for name, var in variables.items()}
        self._variables = variables

    def of(self, state: int) -> dict:
        values = {}
        for name, bits in self._bits.items():
            var = self._variables[name]
            code = sum(1 << bit for bit, states in enumerate(bits) if states.get(state))
            values[name] = bool(code) if var.boolean else var.low + code
        return values


def to_sparse(symbolic, variables: dict):
    """The model built as decision diagrams (with :func:`valuation_labels`) in sparse form, for a witness or a
    per-state question; returns (model, its valuations). Far faster than building it again state by state (the
    assembly bench's 1.25 million states: 16 s against about 100 s)."""
    _quiet()
    import stormpy.transformations

    sparse = stormpy.transformations.transform_to_sparse_model(symbolic)
    return sparse, LabelledValuations(sparse, variables)


def _initial_value(stormpy, model, formula):
    result = stormpy.model_checking(model, formula, only_initial_states=True)
    if model.is_symbolic_model:
        result.filter(stormpy.create_filter_initial_states(model))
        return result.exists_true() if hasattr(result, "exists_true") else result.get_max()
    initial = model.initial_states[0]
    return result.get_value(initial) if hasattr(result, "get_value") else bool(result.get_truth_values_vector()[initial])


def obligation_formula(label: str, periods: int) -> str:
    """The largest probability of reaching a state where an obligation ``G(a -> (b U[0, n] c))`` starts (``a``) and
    some path breaks it (not every path has ``c`` within ``periods`` steps, ``b`` until then), on the labels of its
    parts (``<label>_oa``, ``_ob``, ``_oc``): its value without its monitor. The monitor follows the oldest pending
    obligation (:mod:`cellsim.verify.properties`), and the oldest breaks whenever a younger one does (its window ends
    first, and ``b`` must hold over a longer stretch), so where every update is certain the two reach a violation on
    the same paths. (With a probabilistic update this counts every path from a state where a violation is merely
    possible: more than the monitor. Such a cell keeps its monitors: :func:`cellsim.verify.run._probabilistic`.)"""
    return (f'Pmax=? [ F ("{label}_oa" & !(Pmin>=1 [ "{label}_ob" U<={periods} "{label}_oc" ])) ]')


def check(program, model, prop: Property, bad_label: str | None, still: tuple[str, ...] = (),
          valuations: LabelledValuations | None = None, monitored: bool = True) -> Checked:
    """``still``: the people's place variables, which a witness moves as little as it can; ``valuations``: the
    states' valuations of a model made sparse from decision diagrams (:func:`to_sparse`; a model built state by
    state keeps its own); ``monitored``: whether the program has the monitors (else an obligation is checked by
    :func:`obligation_formula`)."""
    stormpy = _quiet()
    if bad_label and getattr(prop, "obligation", None) and not monitored:
        text = obligation_formula(bad_label, prop.obligation[3])
    else:
        text = f'Pmax=? [ F "{bad_label}" ]' if bad_label else prop.pctl
    start = time.perf_counter()
    try:
        (formula,) = stormpy.parse_properties(text, program)
    except Exception as e:  # noqa: BLE001
        raise VerifyError(f"property {prop.name}: Storm cannot read {prop.pctl or text!r}: {' '.join(str(e).split())[:300]}") from None
    try:
        value = _initial_value(stormpy, model, formula)
    except Exception as e:  # noqa: BLE001 - Storm refuses what it cannot check (G F in a PCTL of an MDP) in many ways
        if bad_label:
            raise
        said = " ".join(str(e).split())[:300] or type(e).__name__
        raise VerifyError(f"verify.{prop.name}: Storm cannot check {prop.description or prop.pctl!r} on this model: "
                          f"{said}") from None
    seconds = time.perf_counter() - start
    if bad_label:
        value = float(value)
        holds = value <= 0.0
        witness = None
        fair = None
        owed = False
        if not holds and prop.response:
            fair = always_answerable(program, model, f"{bad_label}_a", f"{bad_label}_b")
            owed = fair and owed_at_the_end(program, model, f"{bad_label}_a", f"{bad_label}_b",
                                            [f"{bad_label}_end{k}" for k in range(prop.ends)])
            fair = fair and not owed
        elif not holds and not model.is_symbolic_model:
            sustained = f"{bad_label}_sustained" if prop.sustained else None
            if sustained:
                witness = shortest_path(program, model, sustained, required=False, still=still, valuations=valuations)
            witness = witness or shortest_path(program, model, bad_label, still=still, valuations=valuations)
        return Checked(prop, value, time.perf_counter() - start, holds, witness, fair, owed_at_end=owed)
    if isinstance(value, bool):
        return Checked(prop, value, seconds, value)
    return Checked(prop, float(value), seconds, None)


def always_answerable(program, model, a_label: str, b_label: str) -> bool:
    """Whether a ``b`` state can still be reached from every state reachable from an ``a`` state without passing one
    (that ``a`` state included). Then ``G(a -> F b)`` holds on every path that is fair: along which whatever step is
    possible again and again is eventually taken. (Such a path that never met ``b`` again would, in the end, only
    visit states closed under their steps, one of which leads on to ``b``.)

    Asked of Storm as ``Pmax=? [ !b U (Pmax<=0 [ F b ]) ]``: the states from which a path without ``b`` reaches one
    from which ``b`` can never come; none of them may be an ``a`` state. On decision diagrams, as one qualitative
    question of the initial state: can it reach such an ``a`` state (no model need be made sparse for it)."""
    stormpy = _quiet()
    if model.is_symbolic_model:
        text = (f'Pmax>0 [ F ("{a_label}" & !"{b_label}" & Pmax>0 [ !"{b_label}" U (Pmax<=0 [ F "{b_label}" ]) ]) ]')
        (formula,) = stormpy.parse_properties(text, program)
        return not _initial_value(stormpy, model, formula)
    (formula,) = stormpy.parse_properties(f'Pmax=? [ !"{b_label}" U (Pmax<=0 [ F "{b_label}" ]) ]', program)
    values = stormpy.model_checking(model, formula).get_value_vector()
    a, b = model.labeling.get_states(a_label), model.labeling.get_states(b_label)
    return not any(values[s] > 0 for s in range(model.nr_states) if a.get(s) and not b.get(s))


def owed_at_the_end(program, model, a_label: str, b_label: str, end_labels: list[str]) -> bool:
    """Whether a run may end owing a response: from an ``a`` state, without passing ``b``, a state is reachable where
    the people stand as a run may end (each of ``end_labels``: every person at its last stop, one whose end is not
    known at one of its places, as for ``Final`` conditions) from which ``b`` can never come while they stay there.
    The twin's run does end with them standing so, and its check judges ``F b`` strongly: a response still owed at
    the end is a violation, which fairness (a person free to leave does leave) cannot answer when the script has
    them stay. One qualitative question of the initial state, on decision diagrams or sparse alike; with no ways
    given (too many to ask), a run is taken to be able to end owing it."""
    if not end_labels:
        return True
    stormpy = _quiet()
    stuck = " | ".join(f'("{end}" & Pmax<=0 [ "{end}" U "{b_label}" ])' for end in end_labels)
    text = f'Pmax>0 [ F ("{a_label}" & !"{b_label}" & Pmax>0 [ !"{b_label}" U (!"{b_label}" & ({stuck})) ]) ]'
    (formula,) = stormpy.parse_properties(text, program)
    return bool(_initial_value(stormpy, model, formula))


def shortest_path(program, model, label: str, required: bool = True, still: tuple[str, ...] = (),
                  valuations: LabelledValuations | None = None) -> list[dict] | None:
    """The valuations along a shortest path from the initial state to a state labelled ``label``
    (None when none is reachable and not ``required``).

    Storm gives every state's fewest periods to ``label`` (``R{"periods"}min``, every step
    being certain); the path follows them down from the initial state, at each step to a
    successor one period nearer where the fewest of the variables ``still`` (the people's
    places) change: a witness without needless steps (chosen step by step, not over the whole path)."""
    stormpy = _quiet()
    (formula,) = stormpy.parse_properties(f'R{{"{PERIODS}"}}min=? [ F "{label}" ]', program)
    distance = stormpy.model_checking(model, formula).get_value_vector()
    matrix = model.transition_matrix
    valuation = _valuation_of(model, valuations)
    bad = model.labeling.get_states(label)
    state = model.initial_states[0]
    if not math.isfinite(distance[state]):
        if not required:
            return None
        raise VerifyError(f"no path reaches '{label}' although its probability is above 0")
    path = [state]
    while not bad.get(state):
        here = valuation(state)
        nearer = {entry.column for row in range(matrix.get_row_group_start(state), matrix.get_row_group_end(state))
                  for entry in matrix.get_row(row) if entry.value > 0 and distance[entry.column] <= distance[state] - 0.5}
        state = min(nearer, key=lambda s: (sum(valuation(s)[v] != here[v] for v in still if v in here), s))
        path.append(state)
    return [valuation(s) for s in path]


def _valuation_of(model, valuations: LabelledValuations | None):
    """``state -> {variable: value}``: from ``valuations``, else from the model's own state valuations."""
    if valuations is not None:
        return valuations.of
    kept = model.state_valuations
    variables = list(kept.get_all_variables()) if hasattr(kept, "get_all_variables") else []
    return lambda state: {v.name: _plain(kept.get_value(state, v)) for v in variables}


def _plain(value):
    if isinstance(value, bool):
        return value
    try:
        return int(value)
    except (TypeError, ValueError):
        text = str(value)
        return text == "true" if text in ("true", "false") else text
