"""The validation file's conditions, and the user's own PCTL, as properties of the abstract model.

A condition whose shape the abstract model can carry becomes a safety property:

* ``G(p)``, ``p`` without time: an invariant; its bad states are those where ``p``
  fails (where a signal it reads is over-approximated and has a firm formula, its
  witness is sought first where ``p`` fails on the firm formulas too);
* ``G(a -> (b U[0, w] c))`` and ``G(a -> F[0, w] c)`` (the detection conditions):
  a monitor module follows the oldest pending obligation (``a`` held, ``c`` not yet),
  with ``w`` counted in whole periods (rounded down); the bad states are those
  where ``b`` fails or ``w`` runs out before ``c``. The second kind, a miss that
  lasts the whole window, is the *sustained* violation: its witness does not hang
  on the order of events within a period or two, so it is the one replayed first.

A liveness condition ``G(a -> F b)`` is checked as the stronger bounded response
``G(a -> F[0, w] b)`` with ``w`` RESPONSE_PERIODS periods: when it holds, ``b`` follows
``a`` that soon whatever the people and the robot's pace do, so the condition holds.
When it fails, ``b`` may take longer, or wait on something the abstraction leaves
free forever (a person who never leaves): it is then judged under fairness
(:func:`cellsim.verify.storm.always_answerable`), and no witness is run on the twin.

A ``Final`` condition ``F G(p)`` (how a run ends; on a finite trace, ``p`` at its
last sample) is judged where a run can end: in every state where each person
stands where its script leaves it (``PersonRole.end``), ``p`` must hold. The
model has no clock to the horizon, so any such state counts as a run's last (more
endings than the twin's, never fewer); that the people do end there is the stated
assumption, which the twin's runs check. A person whose script may not be over by
the run's end may stand anywhere then. A condition that reads only the people's
own signals (their zone, their flags) is decided at their last stops, without
cutting the floor by what it reads.

Any other shape (a timed ``F`` outside ``G``) is listed as not checked, with the
reason: the abstract model has no end of run.
A condition reading a signal no abstraction defines (the ground truth's
separation) is listed as not checked too.

The user's properties (``verify:`` in the validation file) are PCTL as Storm reads
it, where each double-quoted string is a formula of the condition language in
the cell's own names: ``Pmax=? [ F "HS == act and oloc == inCell" ]``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from cellsim.logic.syntax import (Always, And, Const, Eventually, FormulaError, Implies, Until, is_temporal, numeric_comparisons,
                                  signed_comparisons,
                                  parse, variables_of)
from cellsim.verify.expressions import VerifyError, to_prism
from cellsim.verify.model import AbstractCell, Property
from cellsim.verify.prism import Command, Module, Var


RESPONSE_PERIODS = 2
"""Periods within which a liveness condition's response is sought (``G(a -> F b)`` as ``G(a -> F[0, w] b)``):
what a controller does on its own, a phase it enters unconditionally, takes a period (one more of slack; each
more makes the model larger)."""


@dataclass
class Skipped:
    name: str
    reason: str


@dataclass
class Candidate:
    """A condition to check, once the signals it reads are known to be defined."""

    name: str
    description: str
    shape: str  # "invariant", "final" (F G p), "bounded response" or "response" (G(a -> F b), within RESPONSE_PERIODS)
    parts: tuple  # (p,) or (a, b, c, w)
    variables: dict[str, str]  # trace variable -> channel


class ConditionProperties:
    """Round 1: read what the conditions read; round 2: their properties (or why not)."""

    def __init__(self, cell: AbstractCell, case, validation, asked=None):
        self.cell, self.case, self.validation = cell, case, validation
        self.asked = asked or (lambda name: True)
        """Whether a property of this name is asked for (``verify --only``); the others are not declared."""
        self.unasked: list[str] = []
        self.aliases = dict(validation.variables)
        self.candidates: list[Candidate] = []
        self.skipped: list[Skipped] = []
        self.user: list[tuple[str, str, str]] = []  # (name, pctl text, description)
        self._final_assumed = False
        self._response_assumed = False

    def channel(self, variable: str) -> str:
        return self.aliases.get(variable, variable)

    def declare(self, vocabulary) -> None:
        from cellsim.config.validation import description_of

        for name, formula in self.case.conditions.items():
            if not self.asked(name):  # (what it reads is not read for it: no floor cut, no signal measured)
                self.unasked.append(name)
                continue
            description = description_of(self.validation.conditions[name])
            shape = _shape(formula)
            if isinstance(shape, str):
                self.skipped.append(Skipped(name, shape))
                continue
            kind, parts = shape
            variables = {v: self.channel(v) for v in variables_of(formula)}
            if kind == "final":
                ended = self._at_the_end(parts[0], variables, vocabulary)
                if ended is not None:
                    self.candidates.append(Candidate(name, description or str(name), kind, (Const(ended),), {}))
                    continue
            self.candidates.append(Candidate(name, description or str(name), kind, parts, variables))
            self._reads(formula, variables, f"condition {name}")
        for name, entry in getattr(self.validation, "verify", {}).items():
            if not self.asked(name):
                self.unasked.append(name)
                continue
            self.user.append((name, entry if isinstance(entry, str) else entry.formula,
                              "" if isinstance(entry, str) else entry.description))

    def _at_the_end(self, p, variables: dict[str, str], vocabulary) -> bool | None:
        """``p``'s value where the people's scripts leave them, when it reads only the people's own signals (their
        zone, their flags: functions of where each stands) and each of those people has a known end; else None.
        Decided here, such a ``Final`` condition does not cut the floor by what it reads."""
        from cellsim.logic.predicates import compile_predicate

        own = {f"{r.module}.{port}": (r, fn) for r in self.cell.people for port, fn in r.own.items()}
        if not variables or any(ch not in own or own[ch][0].end is None for ch in variables.values()):
            return None
        values = {v: own[ch][1](own[ch][0].end) for v, ch in variables.items()}
        try:
            return bool(compile_predicate(p, vocabulary)(values))
        except (FormulaError, KeyError):
            return None

    def _reads(self, formula, variables: dict[str, str], by: str) -> None:
        for channel in variables.values():
            self.cell.read(channel, by, required=False)
        for node in numeric_comparisons(formula):
            self.cell.compares(self.channel(node.var), [node.value])
        for node, positive in signed_comparisons(formula):
            self.cell.signed.setdefault(self.channel(node.var), set()).add((node.op, positive))

    def build(self) -> None:
        cell = self.cell
        for c in self.candidates:
            undefined = sorted({v for v, ch in c.variables.items() if ch not in cell.signals})
            if undefined:
                why = [cell.unmodelled[c.variables[v]] for v in undefined if c.variables[v] in cell.unmodelled]
                self.skipped.append(Skipped(c.name, f"reads {', '.join(undefined)}, which no abstraction models"
                                            + "".join(f": {w}" for w in dict.fromkeys(why))))
                continue
            encodings = {v: cell.signals[ch].encoding for v, ch in c.variables.items()}
            names = {v: cell.signals[ch].formula for v, ch in c.variables.items()}
            obligation = None
            try:
                if c.shape == "invariant":
                    bad, sustained = f"!({to_prism(c.parts[0], encodings, names)})", ""
                    firm = {v: cell.signals[ch].firm or names[v] for v, ch in c.variables.items()}
                    if firm != names:  # (a subset of bad: the witness sought first)
                        sustained = f"({bad}) & !({to_prism(c.parts[0], encodings, firm)})"
                elif c.shape == "final":
                    bad, sustained = self._final(c, encodings, names), ""
                else:
                    bad, sustained, obligation = self._monitor(c, encodings, names)
            except VerifyError as e:
                self.skipped.append(Skipped(c.name, str(e)))
                continue
            within = response = None
            if c.shape == "response":
                within = RESPONSE_PERIODS * cell.period
                response = tuple(to_prism(c.parts[i], encodings, names) for i in (0, 2))
                if not self._response_assumed:
                    self._response_assumed = True
                    cell.assume(RUN_GOES_ON)
            cell.properties.append(Property(c.name, c.description, bad=bad, condition=c.name, sustained=sustained,
                                            within=within, response=response, final=c.shape == "final",
                                            obligation=obligation))

    def _final(self, c: Candidate, encodings, names) -> str:
        """``F G p`` (how a run ends): its bad states are those where every person stands where its script leaves it
        at the run's end (``PersonPlaces.end``) and ``p`` fails. Any such state may be the run's last one: the twin's
        run ends there when the person's walk is over. A person whose script may not be over by then may stand
        anywhere (more endings, never fewer)."""
        people = self.cell.places.people if self.cell.places is not None else []
        if not self._final_assumed:
            self._final_assumed = True
            where = "; ".join(f"{p.role.ends}{'' if p.end is not None else ', so it may stand anywhere then'}"
                              for p in people) or "no person walks in the cell"
            self.cell.assume("a Final condition (F G p) is judged in every state where each person stands where its "
                             f"script leaves it ({where}); any such state may be a run's last, whatever the rest "
                             "of the cell is doing then")
        at_end = [f"{p.variable} = {p.end}" for p in people if p.end is not None]
        return f"{' & '.join(at_end) + ' & ' if at_end else ''}!({to_prism(c.parts[0], encodings, names)})"

    def _monitor(self, c: Candidate, encodings, names) -> tuple[str, str, tuple[str, str, str, int]]:
        """The monitor of ``G(a -> (b U[0, w] c))``; returns its bad states, its sustained ones, and the obligation
        (a, b, c, w in periods) as the whole cell's decision diagrams check it without the monitor
        (:func:`cellsim.verify.storm.obligation_formula`)."""
        a, b, cc, w = c.parts
        pa, pb, pc = (to_prism(f, encodings, names) for f in (a, b, cc))
        n = RESPONSE_PERIODS if c.shape == "response" else math.floor(w / self.cell.period + 1e-9)
        ident = "mon_" + re.sub(r"\W", "_", c.name)
        age = f"{ident}_age"
        pending = f"({age} > 0 | {pa})"
        older = f"({age} > 0 ? {age} - 1 : 0)"
        fails = f"({pending} & !{pc} & (!{pb} | {older} >= {n}))"
        sustained = f"({pending} & !{pc} & {pb} & {older} >= {n})"
        self.cell.monitors[c.name] = Module(
            ident, [Var(age, 0, n + 1, 0)], [Command("true", (("1", {age: f"(!{pending} | {pc} | {fails} ? 0 : {older} + 2)"}),))],
            comment=f"monitor of {c.name}: periods since its oldest pending obligation (+1); "
                    "the obligation fails in a state where it is pending and its window ran out or its 'while' part broke")
        return fails, sustained, (pa, pb, pc, n)

    def user_properties(self, vocabulary, macros) -> list[Property]:
        """The user's PCTL, each quoted formula of the condition language a label of its own."""
        cell, out = self.cell, []
        for name, text, description in self.user:
            def label(match, name=name):
                source = match.group(1)
                try:
                    formula = parse(source, vocabulary, macros)
                except FormulaError as e:
                    raise VerifyError(f"verify.{name}: \"{source}\": {e.message}") from None
                if is_temporal(formula):
                    raise VerifyError(f"verify.{name}: \"{source}\" has a temporal operator; write time with PCTL's own")
                variables = {v: self.channel(v) for v in variables_of(formula)}
                missing = sorted(v for v, ch in variables.items() if ch not in cell.signals)
                if missing:
                    raise VerifyError(f"verify.{name}: {', '.join(missing)} has no abstraction in the model")
                encodings = {v: cell.signals[ch].encoding for v, ch in variables.items()}
                names = {v: cell.signals[ch].formula for v, ch in variables.items()}
                key = f"u{len(cell.labels)}"
                cell.labels[key] = to_prism(formula, encodings, names)
                return f'"{key}"'

            pctl = re.sub(r'"([^"]*)"', label, text)
            _readable(name, text, pctl)
            out.append(Property(name, description or text, pctl=pctl))
        return out

    def declare_user(self, vocabulary, macros) -> None:
        """Round 1 for the user's properties: read what their quoted formulas read."""
        for name, text, _ in self.user:
            for source in re.findall(r'"([^"]*)"', text):
                try:
                    formula = parse(source, vocabulary, macros)
                except FormulaError as e:
                    raise VerifyError(f"verify.{name}: \"{source}\": {e.message}") from None
                self._reads(formula, {v: self.channel(v) for v in variables_of(formula)}, f"verify.{name}")


def _readable(name: str, text: str, pctl: str) -> None:
    """VerifyError quoting the user's ``text`` (not its labels) when Storm cannot read ``pctl``, or when it is no
    property the abstraction can answer for the cell (:func:`_unsound`): said before any model is built, not once
    Storm checks it."""
    from cellsim.verify.storm import _quiet

    stormpy = _quiet()
    try:
        read = stormpy.parse_properties(pctl)  # (no program: the syntax alone)
    except Exception as e:  # noqa: BLE001 - Storm's parser errors are one long text
        raise VerifyError(f"verify.{name}: Storm cannot read {text!r} as PCTL: "
                          f"{' '.join(str(e).split())[:200]}") from None
    if len(read) != 1:
        raise VerifyError(f"verify.{name}: {text!r} is {len(read)} properties: write one per name")
    why = _unsound(read[0].get_raw_formula())
    if why:
        raise VerifyError(f"verify.{name}: {text!r} {why}")


def _unsound(formula) -> str:
    """Why a user's PCTL ``formula`` (stormpy's) is not checked, or "": the abstract model allows every behaviour of
    the cell and more, so a bound it meets carries over to the cell only when it is an upper bound over every way
    the model's choices go (``P<=p``, ``P<p``, ``Pmax<=p``); a value (``P=?``, ``Pmax=?``, ``Pmin=?``) is reported
    as the model's. A time bound counts the model's steps, a whole number."""
    from stormpy.logic import ComparisonType, OptimizationDirection

    usage = ("(write P<=p [ ... ], nothing of it happens beyond p whatever the people do, or ask Pmax=? [ ... ] for "
             "the model's value)")
    if not formula.is_probability_operator_formula:
        return f"is not a probability: only P<=p [ ... ] is judged and P=? [ ... ] reported {usage}"
    if formula.has_bound:
        if formula.comparison_type not in (ComparisonType.LEQ, ComparisonType.LESS):
            return ("claims something can happen: holding in the model, which allows more than the cell does, says "
                    f"nothing of the cell {usage}")
        if formula.has_optimality_type and formula.optimality_type != OptimizationDirection.MAXIMIZE:
            return ("claims some way of the model's choices avoids it (Pmin): holding in the model, which allows more "
                    f"than the cell does, says nothing of the cell {usage}")
    path = str(formula.subformula)
    if re.search(r"\b(P|R|LRA|T|S)(max|min)?\s*(\{[^}]*\})?\s*(<|<=|>|>=|=)", path):
        return ("has an operator inside another: a nested probability the model meets in fewer states than the cell "
                "does would make the outer bound prove what the cell may not show; write one bound over quoted formulas")
    if "/" in path:
        return "has a bound that is not a whole number of steps (one step is the model's period)"
    return ""


RUN_GOES_ON = ("a liveness condition G(a -> F b) is judged as if the run went on after a response is owed (the model "
               "has no end of run; the twin's check fails a response still owed when the run ends): one that cannot "
               "come while the people stand where their scripts leave them ends undecided, and one that can is "
               "assumed to come before the run ends (a run cut within its response time of an a is the twin's check "
               "to judge)")


def _shape(formula):
    """("invariant", (p,)), ("final", (p,)), ("bounded response", (a, b, c, w)) or ("response", (a, true, b, inf)),
    else why not (a string)."""
    if (isinstance(formula, Eventually) and isinstance(formula.arg, Always) and _timeless(formula.arg.arg)
            and formula.lo == 0.0 and formula.hi == math.inf and formula.arg.lo == 0.0 and formula.arg.hi == math.inf):
        return "final", (formula.arg.arg,)
    if isinstance(formula, And) and all(_invariant(arg) for arg in formula.args):
        return "invariant", (And(tuple(arg.arg for arg in formula.args)),)  # G(a) and G(b) is G(a and b)
    if not isinstance(formula, Always) or formula.lo != 0.0 or formula.hi != math.inf:
        return "not of the form G(...): a liveness or timed property the abstract model, which has no end of run, cannot judge"
    body = formula.arg
    if not _timeless(body):
        if isinstance(body, Implies) and _timeless(body.lhs):
            rhs = body.rhs
            if isinstance(rhs, Until) and not rhs.weak and rhs.lo == 0.0 and math.isfinite(rhs.hi) and _timeless(rhs.lhs) and _timeless(rhs.rhs):
                return "bounded response", (body.lhs, rhs.lhs, rhs.rhs, rhs.hi)
            if isinstance(rhs, Eventually) and rhs.lo == 0.0 and math.isfinite(rhs.hi) and _timeless(rhs.arg):
                return "bounded response", (body.lhs, Const(True), rhs.arg, rhs.hi)
            if isinstance(rhs, Eventually) and rhs.lo == 0.0 and not math.isfinite(rhs.hi) and _timeless(rhs.arg):
                return "response", (body.lhs, Const(True), rhs.arg, math.inf)
        return "its shape is neither G(p) nor G(a -> (b U[0, w] c)) nor G(a -> F[0, w] c)"
    return "invariant", (body,)


def _invariant(formula) -> bool:
    """``G(p)`` with ``p`` without time."""
    return isinstance(formula, Always) and formula.lo == 0.0 and formula.hi == math.inf and _timeless(formula.arg)


def _timeless(formula) -> bool:
    return not is_temporal(formula)
