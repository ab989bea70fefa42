"""A table over a variable (a place's reading, a sensor's code) in the abstract model, read back by Storm's own
expression evaluator: the chain for a few runs of equal values, the search tree for many, each the table exactly."""

from __future__ import annotations

import numpy as np
import pytest
import stormpy.expressions as expressions

from cellsim.verify.model import TREE_FROM, lookup, set_of


def _evaluate(text: str, values: range, boolean: bool) -> list:
    """``text`` over the integer variable ``x``, evaluated by Storm at each of ``values``."""
    manager = expressions.ExpressionManager()
    x = manager.declare_integer_variable("x")
    parser = expressions.ExpressionParser(manager)
    parser.set_identifier_mapping({"x": x.get_expression()})
    expr = parser.parse_from_string(text)
    out = []
    for v in values:
        at = expr.substitute({x: manager.integer(v)})
        out.append(at.evaluate_as_bool() if boolean else at.evaluate_as_int())
    return out


@pytest.mark.parametrize("seed", range(6))
def test_a_lookup_and_a_set_mean_their_table_whatever_their_form(seed):
    rng = np.random.default_rng(seed)
    size = int(rng.integers(3, 60))
    keys = sorted(rng.choice(np.arange(-1, 90), size=size, replace=False).tolist())
    table = {k: int(rng.integers(-1, 4 if seed % 2 else 12)) for k in keys}
    text = lookup("x", table, -1)
    span = range(-4, 95)
    assert _evaluate(text, span, False) == [table.get(v, -1) for v in span]
    members = [k for k in keys if rng.random() < 0.5]
    assert _evaluate(set_of("x", members), span, True) == [v in members for v in span]


def test_many_runs_make_a_tree_few_a_chain():
    """The tree asks one test per level; a table of a few runs stays the chain an exported model reads best in."""
    many = {k: k % 3 for k in range(40)}
    few = {k: 1 for k in range(10, 20)}
    assert lookup("x", many, -1).count("x<") <= 2 * len(many) and "x=" not in lookup("x", many, -1)
    assert lookup("x", few, -1) == "(((x>=10&x<=19)) ? 1 : -1)" and TREE_FROM > 3
