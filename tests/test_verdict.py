"""One vocabulary of verdicts (cellsim.validation.verdict): a condition's, and a run's over its conditions."""

from __future__ import annotations

import json

from cellsim.validation.verdict import RUN_GROUPS, Verdict


def test_a_runs_verdict_is_the_worst_of_its_conditions_or_failed():
    assert Verdict.of_run([]) is Verdict.HOLDS
    assert Verdict.of_run(["holds", Verdict.INCONCLUSIVE]) is Verdict.INCONCLUSIVE
    assert Verdict.of_run([Verdict.INCONCLUSIVE, "missing data"]) is Verdict.MISSING_DATA
    assert Verdict.of_run(["missing data", "violated", "holds"]) is Verdict.VIOLATED
    assert Verdict.of_run(["holds"], failed=True) is Verdict.FAILED


def test_verdicts_are_written_as_their_words_and_grouped_for_display():
    assert json.dumps({"v": Verdict.MISSING_DATA}) == '{"v": "missing data"}'
    assert [v.group for v in Verdict] == ["holds", "violated", "undecided", "undecided", "failed"]
    assert set(RUN_GROUPS) == {v.group for v in Verdict}
