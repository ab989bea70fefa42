"""Every pass over the condition language knows every operator: a new one cannot be forgotten.

A pass that does something different per operator is a ``Visitor``
(``cellsim.logic.syntax``): it defines ``visit_<Class>`` for each node class, or
names the class in ``refused`` with the reason. The walks that do the same at every
node (``walk``, ``variables_of``, ``is_temporal``) go through each node's
``children()``, so they are checked here by rebuilding every kind of node.
"""

from __future__ import annotations

import importlib
import math
import typing

import pytest

from cellsim.logic import syntax
from cellsim.logic.syntax import (
    NODE_CLASSES,
    Always,
    And,
    BoolVar,
    Compare,
    Const,
    Eventually,
    Implies,
    InSet,
    Node,
    Not,
    Or,
    Until,
    Visitor,
    is_temporal,
    variables_of,
    walk,
)

PASS_MODULES = (
    "cellsim.logic.syntax",
    "cellsim.logic.mtl",
    "cellsim.logic.robustness",
    "cellsim.logic.predicates",
    "cellsim.validation.explain",
    "cellsim.verify.expressions",
)
"""The modules that define passes over the language (importing them registers their visitors)."""


def _passes() -> list[type[Visitor]]:
    for name in PASS_MODULES:
        importlib.import_module(name)
    found, todo = [], list(Visitor.__subclasses__())
    while todo:
        cls = todo.pop()
        found.append(cls)
        todo.extend(cls.__subclasses__())
    return sorted({c for c in found if c.__module__.startswith("cellsim.")}, key=lambda c: c.__qualname__)


PASSES = _passes()
NAMES = {cls.__name__ for cls in NODE_CLASSES}


def test_the_node_classes_are_all_listed():
    defined = {obj for name, obj in vars(syntax).items()
               if isinstance(obj, type) and issubclass(obj, Node) and obj is not Node and not name.startswith("_")}
    assert defined == set(NODE_CLASSES)
    assert typing.get_args(syntax.Formula) == NODE_CLASSES
    assert len(PASSES) >= 10  # the printer, checker, evaluator, margins, compiler, PRISM, explanations


@pytest.mark.parametrize("visitor", PASSES, ids=lambda c: f"{c.__module__}.{c.__qualname__}")
def test_every_pass_handles_or_refuses_every_node_class(visitor):
    handled = {name for name in NAMES if callable(getattr(visitor, "visit_" + name, None))}
    refused = set(visitor.refused)
    missing = NAMES - handled - refused
    assert not missing, f"{visitor.__qualname__} neither handles nor refuses {sorted(missing)}"
    assert not handled & refused, f"{visitor.__qualname__} both handles and refuses {sorted(handled & refused)}"
    assert refused <= NAMES and all(isinstance(why, str) and why for why in visitor.refused.values())
    strays = {m[len("visit_"):] for m in dir(visitor) if m.startswith("visit_")} - NAMES
    assert not strays, f"{visitor.__qualname__} has methods for no node class: {sorted(strays)}"


def test_a_pass_missing_a_method_or_refusing_says_which_and_why():
    class Half(Visitor):
        refused = {"Not": "no negation here"}

        def visit_Const(self, node):
            return node.value

    assert Half().visit(Const(True)) is True
    with pytest.raises(NotImplementedError, match="Half has no visit_BoolVar"):
        Half().visit(BoolVar("p"))
    with pytest.raises(TypeError, match="no negation here"):
        Half().visit(Not(Const(True)))
    with pytest.raises(TypeError, match="not a formula"):
        Half().visit("p")


EXAMPLES = [
    Const(True),
    BoolVar("p"),
    Compare("x", "<=", 0.5),
    Compare("x", "<", None, "y"),
    InSet("m", frozenset({"a", "b"})),
    Not(BoolVar("p")),
    And((BoolVar("p"), BoolVar("q"), Const(False))),
    Or((BoolVar("p"), BoolVar("q"))),
    Implies(BoolVar("p"), BoolVar("q")),
    Always(BoolVar("p"), 0.5, 2.0),
    Eventually(BoolVar("p"), 0.0, math.inf),
    Until(BoolVar("p"), BoolVar("q"), 1.0, 3.0, weak=True),
]


def test_the_examples_cover_every_node_class():
    assert {type(e) for e in EXAMPLES} == set(NODE_CLASSES)


@pytest.mark.parametrize("node", EXAMPLES, ids=lambda n: type(n).__name__)
def test_a_node_rebuilt_from_its_children_is_itself(node):
    assert node.with_children(*node.children()) == node
    others = tuple(Const(i % 2 == 0) for i in range(len(node.children())))
    rebuilt = node.with_children(*others)
    assert type(rebuilt) is type(node) and rebuilt.children() == others


def test_walk_visits_every_node_in_written_order():
    f = Always(Implies(And((BoolVar("a"), Compare("x", "<", None, "y"))), Until(BoolVar("b"), Not(BoolVar("c")))))
    kinds = [type(n).__name__ for n in walk(f)]
    assert kinds == ["Always", "Implies", "And", "BoolVar", "Compare", "Until", "BoolVar", "Not", "BoolVar"]
    assert variables_of(f) == {"a", "b", "c", "x", "y"}
    assert is_temporal(f) and not is_temporal(f.arg.lhs)
    assert [n.temporal for n in EXAMPLES].count(True) == 3
    with pytest.raises(TypeError, match="not a formula"):
        list(walk(Not("p")))  # type: ignore[arg-type]
