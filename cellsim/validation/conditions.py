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
from dataclasses import dataclass

from cellsim.config.typed_yaml import ConfigError
from cellsim.logic.mtl import TraceEvaluator, Verdict
from cellsim.logic.syntax import Formula, FormulaError, parse
from cellsim.logic.trace import Trace
from cellsim.validation.config import Validation
from cellsim.validation.coverage import CoverageModel

Locate = Callable[[str], tuple[str, int | None, str]]
"""Dotted key of the validation section -> (file, line, key in that file) where it is written."""


@dataclass
class CheckResult:
    """The verdict of every condition on one run, and the use cases it exercised."""

    verdicts: dict[str, Verdict]
    use_cases: list[str]
    coverage: dict[str, list[list[str]]]

    @property
    def violations(self) -> list[str]:
        return [name for name, v in self.verdicts.items() if not v.holds]

    def verdicts_json(self) -> dict[str, dict]:
        return {name: {"holds": v.holds, "violated_at": v.violated_at} for name, v in self.verdicts.items()}


@dataclass
class SafetyCase:
    """Compiled conditions, use cases and coverage model of a scenario."""

    validation: Validation
    conditions: dict[str, Formula]
    use_cases: dict[str, Formula]
    coverage: CoverageModel

    @classmethod
    def compile(cls, validation: Validation, vocabulary: dict, locate: Locate) -> SafetyCase:
        """Parse and type-check everything; raises ConfigError at the offending key."""

        def formula(key: str, text: str) -> Formula:
            try:
                return parse(text, vocabulary, validation.macros)
            except FormulaError as e:
                where = f"column {e.column} of the formula: " if e.column is not None else ""
                raise ConfigError(*locate(key), where + e.message) from None

        for name, text in validation.macros.items():
            formula(f"validation.macros.{name}", text)
        conditions = {name: formula(f"validation.conditions.{name}", t) for name, t in validation.conditions.items()}
        use_cases = {name: formula(f"validation.use_cases.{name}", t) for name, t in validation.use_cases.items()}
        try:
            coverage = CoverageModel.compile(
                validation.coverage, vocabulary, validation.macros, validation.bins, validation.domains
            )
        except ValueError as e:
            raise ConfigError(*locate("validation.coverage"), str(e)) from None
        return cls(validation, conditions, use_cases, coverage)

    def check(self, trace: Trace) -> CheckResult:
        """Verdicts, use cases and covered situations of one trace."""
        evaluator = TraceEvaluator(trace)
        verdicts = {name: evaluator.evaluate(f) for name, f in self.conditions.items()}
        use_cases = [name for name, f in self.use_cases.items() if evaluator.evaluate(f).holds]
        coverage = self.coverage.observe(trace, set(use_cases), evaluator)
        return CheckResult(verdicts, use_cases, coverage)
