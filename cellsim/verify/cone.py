"""A property's cone of influence: the modules whose values can change what its labels read.

Every module of the abstract cell takes exactly one ``[step]`` command each period, all reading the state before it
(:mod:`cellsim.verify.prism`), and a state where some module has no command enabled is refused as a bug of its
abstraction (:func:`cellsim.verify.storm.build`). So a module that neither a label nor any module in the cone reads
cannot change what the labels see: its guards may read the cone's variables, but it always has a command to take,
and what it writes nobody in the cone reads. Dropping it keeps, exactly, every path of the cone's variables: the
same probabilities, the same shortest distances to a bad state, the same witnesses' lengths (their states then hold
the cone's variables only). A property is built on its cone (:func:`within_cone`); the modules it drops are named.
"""

from __future__ import annotations

from dataclasses import replace

from cellsim.verify.order import NAME, reads
from cellsim.verify.prism import Program


def variables_read(text: str, program: Program, seen: tuple[str, ...] = ()) -> set[str]:
    """The variables an expression of ``program`` reads, its formulas expanded."""
    owned = {v.name for m in program.modules for v in m.variables}
    found = set()
    for name in NAME.findall(text):
        if name in owned:
            found.add(name)
        elif name in program.formulas and name not in seen:
            found |= variables_read(program.formulas[name], program, (*seen, name))
    return found


def cone(program: Program) -> list[str]:
    """The names of the modules in the cone of influence of ``program``'s labels, in the program's order: those
    a label reads, and every module a module in the cone reads (its guards and updates, formulas expanded)."""
    owner = {v.name: m.name for m in program.modules for v in m.variables}
    read = reads(program.modules, program.formulas)
    inside = {owner[v] for label in program.labels.values() for v in variables_read(label, program)}
    todo = list(inside)
    while todo:
        for other in read[todo.pop()]:
            if other not in inside:
                inside.add(other)
                todo.append(other)
    return [m.name for m in program.modules if m.name in inside]


def within_cone(program: Program) -> tuple[Program, list[str]]:
    """``program`` with only the modules in its labels' cone (:func:`cone`), and the formulas they can read (a
    formula reading a dropped module's variable is read by nobody left); returns (that program, the names of the
    modules dropped). A program whose labels read no variable (none, or constants only) is returned whole: Storm
    needs a module to build a model at all."""
    kept = set(cone(program))
    dropped = [m.name for m in program.modules if m.name not in kept]
    if not kept or not dropped:
        return program, []
    modules = [m for m in program.modules if m.name in kept]
    gone = {v.name for m in program.modules if m.name not in kept for v in m.variables}
    formulas = {name: expr for name, expr in program.formulas.items()
                if not variables_read(expr, program) & gone}
    return replace(program, modules=modules, formulas=formulas), dropped
