"""Hypothesis strategies and reference tables shared by the ``test_logic_*`` files.

A plain module (``tests`` is not a package): pytest puts ``tests/`` on ``sys.path``
for its rootdir-relative test modules, so the tests say ``from logic_strategies import ...``
just as they say ``from conftest import ...``.
"""

from __future__ import annotations

import math
import operator

from hypothesis import strategies as st

from cellsim.logic.syntax import (
    Always,
    And,
    EnumDomain,
    Eventually,
    Implies,
    Not,
    Or,
    Until,
)

# ----------------------------------------------------------------- reference semantics

OPS = {
    "==": operator.eq,
    "!=": operator.ne,
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
}
"""The comparison operators of the language, for the reference evaluators."""

# ----------------------------------------------------------------- vocabularies

HAZARD = EnumDomain(("inact", "act", "mit", "mis"))
SAFMOD = EnumDomain(("normal", "hguid", "ssmon", "pflim", "srmst", "stopped"))
RLOC = EnumDomain(("sharedTbl", "welder", "home"))

# ----------------------------------------------------------------- strategies


@st.composite
def intervals(draw, lows, widths):
    """``(lo, hi)``: ``lo`` from ``lows``; ``hi`` infinite or ``lo`` plus one of ``widths``."""
    lo = draw(lows)
    hi = draw(st.one_of(st.just(math.inf), widths.map(lambda w: lo + w)))
    return lo, hi


def connectives(children, *, max_args: int = 3, intervals=None):
    """One layer of operators over ``children`` (for ``st.recursive``).

    ``not``, ``and``/``or`` of 2 .. ``max_args`` operands and ``->``; with an
    ``intervals`` strategy of ``(lo, hi)`` pairs also ``G``, ``F``, ``U`` and ``W``.
    """
    args = st.lists(children, min_size=2, max_size=max_args).map(tuple)
    options = [
        children.map(Not),
        args.map(And),
        args.map(Or),
        st.builds(Implies, children, children),
    ]
    if intervals is not None:
        options += [
            st.builds(lambda f, iv: Always(f, *iv), children, intervals),
            st.builds(lambda f, iv: Eventually(f, *iv), children, intervals),
            st.builds(
                lambda l, r, iv, w: Until(l, r, *iv, weak=w),
                children,
                children,
                intervals,
                st.booleans(),
            ),
        ]
    return st.one_of(*options)
