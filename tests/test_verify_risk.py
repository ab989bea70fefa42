"""A risk model in PRISM is the engine's risk model: Storm, stepping the translation, agrees with the engine.

For scripted sequences of monitored values (random, sticky so that ``after:`` delays are
reached), the welding and palletising cells' safety controllers are stepped by the engine,
and their PRISM translation, driven by the same script, is built and walked by Storm: the
hazards' phases and the commanded values agree at every period.
"""

from __future__ import annotations

import numpy as np
import pytest
import stormpy

from cellsim.scenario import load_scenario
from cellsim.verify.expressions import Thresholds
from cellsim.verify.prism import Command, Module, Program, Var
from cellsim.verify.risk import risk_modules
from cellsim.diagrams.cell import build_cell

from conftest import ROOT

PERIODS = 1500


def _controller(scenario: str):
    cell = build_cell(load_scenario(ROOT / "scenarios" / scenario), seed=1, duration=5.0, record=False)
    return next(m for m in cell.modules.values() if hasattr(m, "risk_model"))


def _script(controller, seed: int, encodings) -> list[dict]:
    """Monitored values per period, in blocks held for 1 to 40 periods (so that ``after:`` delays are
    reached, and sometimes just missed); between blocks each variable changes with probability 0.3."""
    rng = np.random.default_rng(seed)
    choices = {}
    for name, var in controller.risk_model.monitored.items():
        encoding = encodings[name]
        if isinstance(encoding, Thresholds):  # a number: the thresholds and values between and around them
            points = list(encoding.values)
            choices[name] = sorted({*points, *(p - 0.05 for p in points), *(p + 0.05 for p in points)})
        else:
            choices[name] = list(var.domain)
    current = {name: values[rng.integers(len(values))] for name, values in choices.items()}
    script = []
    while len(script) < PERIODS:
        script += [dict(current)] * int(rng.integers(1, 41))
        for name, values in choices.items():
            if rng.random() < 0.3:
                current[name] = values[rng.integers(len(values))]
    return script[:PERIODS]


def _engine(controller, script) -> list[tuple]:
    """(phases, commands) after each period, as the engine computes them."""
    context = controller.CreateDefaultContext()
    channels = {spec.signal: (spec, port) for spec, port in controller.channels}
    out = []
    for k, values in enumerate(script):
        context.SetTime(k * controller.period)
        controller.monitored_port.FixValue(context, controller.encode_monitored(values))
        context.SetDiscreteState(controller.EvalUniquePeriodicDiscreteUpdate(context))
        phases = tuple(channels[h.name][0].type.decode(channels[h.name][1].Eval(context)) for h in controller.hazards)
        commands = tuple(channels[c][0].type.decode(channels[c][1].Eval(context)) for c in controller.risk_model.controlled)
        out.append((phases, commands))
    return out


def _encode(encoding, value) -> str:
    if encoding is bool:
        return "true" if value else "false"
    if isinstance(encoding, Thresholds):
        return str(encoding.region_of(float(value)))
    return str(encoding.code(value))


def _storm(controller, script, tmp_path) -> list[tuple]:
    """(phases, commands) after each period, as Storm steps the PRISM translation driven by the script."""
    rm = controller.risk_model
    modules = risk_modules(rm, controller.period)
    enc = modules.encodings
    variables = []
    for name in rm.monitored:
        e = enc[name]
        if e is bool:
            variables.append(Var(name, boolean=True, init=bool(script[0][name])))
        else:
            high = e.regions - 1 if isinstance(e, Thresholds) else len(e.values) - 1
            variables.append(Var(name, 0, high, int(_encode(e, script[0][name]))))
    variables.append(Var("k", 0, len(script), 0))
    commands = [Command(f"k = {k}", (("1", {"k": str(k + 1), **{n: _encode(enc[n], script[k + 1][n]) for n in rm.monitored}}),))
                for k in range(len(script) - 1)]
    commands.append(Command(f"k >= {len(script) - 1}", (("1", {"k": str(len(script))}),)))
    commands.append(Command(f"k = {len(script)}", (("1", {}),)))
    labels = {}
    for name, var in rm.controlled.items():
        for i, value in [(-1, None), *enumerate(var.domain)]:
            labels[f"cmd_{name}_{i + 1}"] = f"cmd_{name} = {i}"
    program = Program([Module("script", variables, commands), *modules.modules], modules.formulas, labels)
    path = tmp_path / "controller.prism"
    path.write_text(program.text())
    model = stormpy.build_model(stormpy.parse_prism_program(str(path)), options=stormpy.BuilderOptions(build_full=True))
    assert model.labeling.get_states("deadlock").get_number_of_set_bits() == 0
    valuations, matrix = model.state_valuations, model.transition_matrix
    by_name = {v.name: v for v in valuations.get_all_variables()}
    state = model.initial_states[0]
    out = []
    for _ in script:
        (row,) = range(matrix.get_row_group_start(state), matrix.get_row_group_end(state))  # one choice: no nondeterminism
        (entry,) = list(matrix.get_row(row))  # one successor: deterministic
        state = entry.column
        phases = tuple(modules.phases.values[valuations.get_value(state, by_name[h.name])] for h in rm.hazards)
        state_labels = model.labeling.get_labels_of_state(state)
        commands = []
        for name, var in rm.controlled.items():
            (i,) = [i for i in range(-1, len(var.domain)) if f"cmd_{name}_{i + 1}" in state_labels]
            commands.append(None if i < 0 else var.domain[i])
        out.append((phases, tuple(commands)))
    return out


@pytest.mark.parametrize("scenario", ["welding_cell.yaml", "palletising_cell.yaml"])
def test_storm_stepping_the_translation_agrees_with_the_engine_at_every_period(tmp_path, scenario):
    controller = _controller(scenario)
    encodings = risk_modules(controller.risk_model, controller.period).encodings
    mishap, reached = controller.risk_model.phases.mishap, False
    for seed in (1, 2, 3):
        script = _script(controller, seed, encodings)
        engine = _engine(controller, script)
        assert engine == _storm(controller, script, tmp_path), seed
        reached = reached or any(mishap in phases for phases, _ in engine)
    assert reached  # the scripts drove hazards through their timed transitions into the mishap


def test_a_timed_transition_waits_its_periods_in_the_translation_too():
    controller = _controller("welding_cell.yaml")
    modules = risk_modules(controller.risk_model, controller.period)
    # HS: mit -> mis after 1.0 s; the controller's period makes that a whole number of periods
    assert modules.timers["HS_t3"] == round(1.0 / controller.period)
    text = "\n".join(m.text() for m in modules.modules)
    assert "HS_t3 >= " in text and "min(HS_t3 + 1" in text
