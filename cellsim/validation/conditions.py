"""Safety conditions and use-case classifiers, compiled once and checked on traces.

A :class:`SafetyCase` is a scenario's ``validation`` section parsed against a
vocabulary (the scenario's channels, or a black box's, plus the short names of
``validation.variables``). ``check`` evaluates every condition and every use-case
classifier on one trace with a shared evaluator, so sub-formulas common to
several conditions (the hazards' detection macros) are computed once.

Formula errors become :class:`~cellsim.config.typed_yaml.ConfigError`s naming the
file, the line of the key and the column within the formula.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from cellsim.config.typed_yaml import ConfigError, suggest
from cellsim.logic.mtl import TraceEvaluator
from cellsim.logic.syntax import Formula, FormulaError, parse, variables_of
from cellsim.logic.trace import Trace
from cellsim.config.validation import Validation
from cellsim.validation.coverage import CoverageError, CoverageModel
from cellsim.validation.verdict import Verdict

Locate = Callable[[str], tuple[str, int | None, str]]
"""Dotted key of the validation section -> (file, line, key in that file) where it is written."""




@dataclass(frozen=True)
class ConditionVerdict:
    """A safety condition's verdict on one run.

    ``status`` is one of:

    * ``holds``: the condition holds on the run;
    * ``violated``: it does not; ``violated_at`` is the first violation (for a
      ``G`` condition) or the start;
    * ``inconclusive``: the run did not complete and how it would have gone on
      could change the verdict (a hazard still open at the cut, or any condition
      that has held so far); ``reading`` says what the recorded part shows;
    * ``missing data``: the condition reads a variable with no message at all
      (``missing`` names them): nothing was observed, so nothing is claimed.
    """

    status: Verdict
    violated_at: float | None = None
    missing: tuple[str, ...] = ()
    reading: str | None = None
    """For an inconclusive verdict: ``holds so far`` or ``violated so far``."""
    explanation: str | None = None
    """For a violation: why, at the first violation, in one sentence (``cellsim.validation.explain``)."""
    evidence: dict | None = field(default=None, hash=False)
    """For a violation: the required window and its macros' and atoms' intervals (``Explainer.evidence``)."""

    @property
    def holds(self) -> bool:
        return self.status is Verdict.HOLDS

    def to_json(self) -> dict:
        data = {"holds": self.holds, "status": self.status.value, "violated_at": self.violated_at}
        if self.missing:
            data["missing"] = list(self.missing)
        if self.reading:
            data["reading"] = self.reading
        if self.explanation:
            data["explanation"] = self.explanation
        if self.evidence:
            data["evidence"] = self.evidence
        return data

    def describe(self) -> str:
        """The verdict in a few words, for tables."""
        if self.status is Verdict.MISSING_DATA:
            return f"missing data: {', '.join(self.missing)} never recorded"
        if self.status is Verdict.INCONCLUSIVE:
            return f"inconclusive: {self.reading} when the recording stopped"
        return self.status.value


@dataclass
class CheckResult:
    """The verdict of every condition on one run, and the use cases it exercised."""

    verdicts: dict[str, ConditionVerdict]
    use_cases: list[str]
    coverage: dict[str, list[list[str]]]

    @property
    def violations(self) -> list[str]:
        return [name for name, v in self.verdicts.items() if v.status is Verdict.VIOLATED]

    @property
    def undecided(self) -> list[str]:
        """Conditions that neither hold nor are violated: inconclusive or missing data."""
        return [name for name, v in self.verdicts.items() if v.status.undecided]

    @property
    def all_hold(self) -> bool:
        return all(v.holds for v in self.verdicts.values())

    @property
    def verdict(self) -> Verdict:
        """The run's verdict: the worst of its conditions'."""
        return Verdict.of_run(v.status for v in self.verdicts.values())

    def verdicts_json(self) -> dict[str, dict]:
        return {name: v.to_json() for name, v in self.verdicts.items()}


@dataclass
class SafetyCase:
    """Compiled conditions, use cases and coverage model of a scenario."""

    validation: Validation
    conditions: dict[str, Formula]
    use_cases: dict[str, Formula]
    coverage: CoverageModel
    macros: dict[str, Formula] | None = None
    """Each macro, expanded: the names explanations give the sub-formulas of a condition."""
    guides: dict[str, tuple[Formula, Formula]] = field(default_factory=dict)
    """Each falsification guide's two situations (``validation.guides``)."""

    @classmethod
    def compile(cls, validation: Validation, vocabulary: dict, locate: Locate) -> SafetyCase:
        """Parse and type-check everything; raises ConfigError at the offending key."""

        def formula(key: str, text: str) -> Formula:
            try:
                return parse(text, vocabulary, validation.macros)
            except FormulaError as e:
                where = f"column {e.column} of the formula: " if e.column is not None else ""
                raise ConfigError(*locate(key), where + e.message) from None

        macros = {name: formula(f"validation.macros.{name}", text) for name, text in validation.macros.items()}
        from cellsim.config.validation import Described, formula_of

        def entry(key: str, written) -> Formula:  # a bare formula, or {formula, description}: the formula's line
            return formula(key + (".formula" if isinstance(written, Described) else ""), formula_of(written))

        conditions = {name: entry(f"validation.conditions.{name}", t) for name, t in validation.conditions.items()}
        use_cases = {name: entry(f"validation.use_cases.{name}", t) for name, t in validation.use_cases.items()}
        for name, criterion in validation.coverage.items():
            if criterion.use_case and criterion.use_case not in use_cases:
                hint = suggest(criterion.use_case, use_cases) or f" (use cases: {', '.join(use_cases) or 'none'})"
                raise ConfigError(*locate(f"validation.coverage.{name}.use_case"), f"no use case named '{criterion.use_case}'{hint}")
        try:
            coverage = CoverageModel.compile(
                validation.coverage, vocabulary, validation.macros, validation.bins, validation.domains
            )
        except CoverageError as e:
            raise ConfigError(*locate(f"validation.{e.key}"), str(e)) from None
        except ValueError as e:
            raise ConfigError(*locate("validation.coverage"), str(e)) from None
        for name, g in validation.guides.items():
            for i, target in enumerate(g.conditions):
                if target not in conditions:
                    hint = suggest(target, conditions) or f" (conditions: {', '.join(conditions) or 'none'})"
                    raise ConfigError(*locate(f"validation.guides.{name}.conditions.{i}"), f"no condition named '{target}'{hint}")
        guides = {name: tuple(formula(f"validation.guides.{name}.meet.{i}", text) for i, text in enumerate(g.meet))
                  for name, g in validation.guides.items()}
        return cls(validation, conditions, use_cases, coverage, macros, guides)

    def check(self, trace: Trace, *, complete: bool = True, recorded: set[str] | None = None) -> CheckResult:
        """Verdicts, use cases and covered situations of one trace.

        ``complete`` says whether the trace ends where the run was meant to end
        (otherwise verdicts the cut could change are inconclusive); ``recorded``
        names the variables with at least one message (default: every variable
        whose signal has a sample), the others make their conditions missing data.
        """
        evaluator = TraceEvaluator(trace)
        if recorded is None:
            recorded = {name for name, signal in trace.signals.items() if len(signal)}
        verdicts = {name: self._verdict(evaluator, f, complete, recorded) for name, f in self.conditions.items()}
        use_cases = [name for name, f in self.use_cases.items() if evaluator.evaluate(f).holds]
        coverage = self.coverage.observe(trace, set(use_cases), evaluator)
        return CheckResult(verdicts, use_cases, coverage)

    def _verdict(self, evaluator: TraceEvaluator, formula: Formula, complete: bool, recorded: set[str]) -> ConditionVerdict:
        missing = tuple(sorted(variables_of(formula) - recorded))
        if missing:
            return ConditionVerdict(Verdict.MISSING_DATA, missing=missing)
        evaluation = evaluator.evaluate(formula)
        if not complete and not evaluator.conclusive(formula):
            return ConditionVerdict(
                Verdict.INCONCLUSIVE, evaluation.violated_at, reading="holds so far" if evaluation.holds else "violated so far"
            )
        if evaluation.holds:
            return ConditionVerdict(Verdict.HOLDS, None)
        from cellsim.validation.explain import Explainer

        explainer = Explainer(evaluator, self.macros)
        return ConditionVerdict(
            Verdict.VIOLATED, evaluation.violated_at,
            explanation=explainer.explain(formula, evaluation.violated_at),
            evidence=explainer.evidence(formula, evaluation.violated_at),
        )
