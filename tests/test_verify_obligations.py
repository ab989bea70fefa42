"""A bounded obligation G(a -> (b U[0, n] c)) checked on the whole cell without its monitor: the same value.

The whole cell's decision diagrams are built without the monitors (the palletising cell's four monitors add no
state but cost about a third of its build) and each obligation is checked as a nested formula,
``cellsim.verify.storm.obligation_formula``; the monitors stay in the models built for witnesses.
"""

from __future__ import annotations

import stormpy

from cellsim.scenario import load_scenario
from cellsim.verify.run import abstract_model
from cellsim.verify.storm import _initial_value, build_symbolic, obligation_formula

from conftest import WELDING_CELL


def _value(program, model, text: str) -> float:
    return float(_initial_value(stormpy, model, stormpy.parse_properties(text, program)[0]))


def test_the_window_is_n_steps_after_a_and_a_broken_while_part_breaks_it(tmp_path):
    """A clock counts 0..9; the obligation starts at 1 and is met at 1 + k: within a window of 3 steps it holds for
    k <= 3 and breaks for k = 4; its 'while' part failing before c breaks it too."""
    def program(met_at: int, holding_until: int) -> str:
        return (f"mdp\nmodule clock\n  x : [0..9] init 0;\n  [] x < 9 -> (x'=x+1);\n  [] x = 9 -> true;\nendmodule\n"
                f'label "o_oa" = x = 1;\nlabel "o_ob" = x <= {holding_until};\nlabel "o_oc" = x = {met_at};\n')

    values = {}
    for met_at, holding in ((1, 9), (4, 9), (5, 9), (4, 2), (4, 3)):
        path = tmp_path / f"m{met_at}{holding}.prism"
        path.write_text(program(met_at, holding))
        parsed, model, _ = build_symbolic(path, 32)
        values[met_at, holding] = _value(parsed, model, obligation_formula("o", 3))
    assert values == {(1, 9): 0.0, (4, 9): 0.0, (5, 9): 1.0,  # c at the third step after a: in time; the fourth: late
                      (4, 2): 1.0, (4, 3): 0.0}  # b must hold until c comes (not in the state c holds)


def test_the_welding_cells_obligations_read_the_same_with_their_monitors_and_without(tmp_path):
    """Every detection and liveness condition of the welding cell, violated and holding ones alike, has the same
    value on the whole cell with every monitor in it (its monitor's bad states reached) as on the whole cell without
    any (the nested formula)."""
    model = abstract_model(load_scenario(WELDING_CELL))
    obligations = [p for p in model.properties if p.obligation]
    assert len(obligations) >= 9
    monitored, bare = tmp_path / "monitored.prism", tmp_path / "bare.prism"
    monitored.write_text(model.cell.program(model.header).text())
    bare.write_text(model.cell.program(model.header, [], model.unmonitored_labels()).text())
    assert "mon_" in monitored.read_text() and "mon_" not in bare.read_text()
    with_monitors, without = build_symbolic(monitored, 128), build_symbolic(bare, 128)
    assert without[2].states < with_monitors[2].states  # (the monitors' ages are state of their own here)
    found = {}
    for prop in obligations:
        label = model.labels[prop.name]
        found[prop.name] = (_value(*with_monitors[:2], f'Pmax=? [ F "{label}" ]'),
                            _value(*without[:2], obligation_formula(label, prop.obligation[3])))
    assert all(a == b for a, b in found.values()), found
    assert {a for a, _ in found.values()} == {0.0, 1.0}, found  # both verdicts compared


def test_a_cell_with_a_probabilistic_update_keeps_its_monitors_in_the_whole_cell(tmp_path):
    """A review showed the nested formula counting every path from a state where a violation is merely possible: with
    a probabilistic update its value exceeds the monitor's (1.0 against 0.5 here). No shipped kind's update has a
    probability, but a plug-in's may: such a cell is checked with its monitors in the whole cell."""
    from cellsim.verify.prism import Command, Module, Program, Var
    from cellsim.verify.run import _probabilistic

    coin = Module("m", [Var("s", 0, 2, 0)], [Command("s = 0", (("0.5", {"s": "1"}), ("0.5", {"s": "2"}))),
                                             Command("s > 0", (("1", {}),))])
    certain = Module("m", [Var("s", 0, 2, 0)], [Command("s < 2", (("1", {"s": "s + 1"}),)), Command("s = 2", (("1", {}),))])
    assert _probabilistic(Program([coin], {}, {})) and not _probabilistic(Program([certain], {}, {}))
    path = tmp_path / "coin.prism"
    path.write_text("mdp\nmodule m\n  s : [0..2] init 0;\n  [] s = 0 -> 0.5:(s'=1) + 0.5:(s'=2);\n  [] s > 0 -> true;\n"
                    "endmodule\n" 'label "o_oa" = s = 0;\nlabel "o_ob" = s <= 1;\nlabel "o_oc" = s = 1;\n')
    parsed, model, _ = build_symbolic(path, 32)
    assert _value(parsed, model, obligation_formula("o", 2)) == 1.0  # the monitor's: 0.5 (only the s = 2 branch breaks it)
