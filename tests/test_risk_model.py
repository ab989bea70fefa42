"""The welding cell's risk model, executed by the generic engine on hand-made inputs."""

from __future__ import annotations

import random

import numpy as np
import pytest

from cellsim.kinds.safety_controller.risk_model import load_risk_model
from cellsim.kinds.safety_controller.system import SafetyController
from cellsim.channels import BOOL, enum_type
from cellsim.config.typed_yaml import ConfigError
from cellsim.vocabulary import (
    CodedEnum,
    Range,
    SafetyMode,
)

from conftest import ROOT

RISK_MODEL = ROOT / "scenarios" / "welding_cell_risk_model.yaml"
TYPES = {
    "safmod": enum_type(SafetyMode),
    "rloc": enum_type(CodedEnum("rloc", [(n, n) for n in ("atTable", "sharedTbl", "atWeldSpot", "inCell", "unknown")])),
    "wact": enum_type(CodedEnum("wact", [(n, n) for n in ("idle", "welding", "off")])),
    "ract": enum_type(CodedEnum("ract", [(n, n) for n in ("idle", "exchWrkp", "welding", "off", "unknown")])),
    "rngDet": enum_type(Range),
    "lgtBar": BOOL,
    "notif": enum_type(CodedEnum("notif", [(n, n) for n in ("ok", "leaveArea")])),
    "notif_leaveWrkb": BOOL,
}
COMMANDS = {k: TYPES[k] for k in ("safmod", "ract", "wact", "notif", "notif_leaveWrkb")}
# the cell working normally, nobody around
QUIET = dict(safmod="normal", rloc="inCell", wact="idle", ract="exchWrkp", rngDet="far", lgtBar=False, notif="ok", notif_leaveWrkb=False)


class Harness:
    """Steps the safety controller alone: set inputs, apply one periodic update."""

    def __init__(self, period=0.02):
        self.system = SafetyController("safety_controller", period, load_risk_model(RISK_MODEL), TYPES, COMMANDS)
        self.context = self.system.CreateDefaultContext()
        self.t = 0.0
        self.inputs = dict(QUIET)

    def step(self, **changes):
        self.inputs.update(changes)
        self.system.monitored_port.FixValue(self.context, self.system.encode_monitored(self.inputs))
        self.context.SetTime(self.t)
        state = self.system.EvalUniquePeriodicDiscreteUpdate(self.context)
        self.context.SetDiscreteState(state)
        self.t += self.system.period
        return self

    def phase(self, hazard):
        return self.system.GetOutputPort(hazard).Eval(self.context)[0]

    def phases(self):
        from cellsim.vocabulary import HazardPhase

        return {h: HazardPhase.from_code(self.phase(h)).value for h in ("HRW", "HS", "HC")}

    def command(self, name):
        value = self.system.GetOutputPort(name).Eval(self.context)
        return COMMANDS[name].decode(value) if value[0] != -1 else None


def test_quiet_cell_raises_nothing():
    h = Harness()
    for _ in range(10):
        h.step()
    assert h.phases() == {"HRW": "inact", "HS": "inact", "HC": "inact"}
    assert h.command("safmod") == "normal" and h.command("ract") is None


def test_HRW_detect_mitigate_resume():
    h = Harness().step()
    h.step(rloc="sharedTbl")  # robot at the table, barrier intact: nothing
    assert h.phases()["HRW"] == "inact"
    h.step(lgtBar=True)  # operator's arm over the table
    assert h.phases()["HRW"] == "act"
    h.step()
    assert h.phases()["HRW"] == "mit"
    assert h.command("safmod") == "pflim" and h.command("notif_leaveWrkb") is True
    h.step(safmod="pflim")  # still on the table: stays mitigated
    assert h.phases()["HRW"] == "mit"
    h.step(lgtBar=False)
    assert h.phases()["HRW"] == "res"
    assert h.command("safmod") == "normal" and h.command("notif_leaveWrkb") is False
    h.step()
    assert h.phases()["HRW"] == "inact"


def test_HRW_needs_the_robot_at_the_table_and_the_cell_working():
    h = Harness().step(lgtBar=True, rloc="inCell")
    assert h.phases()["HRW"] == "inact"
    h.step(rloc="sharedTbl", ract="idle", wact="idle")
    assert h.phases()["HRW"] == "inact"
    h.step(ract="exchWrkp")
    assert h.phases()["HRW"] == "act"


def test_HS_detect_mitigate_resume():
    h = Harness().step(rngDet="near")
    assert h.phases()["HS"] == "act"
    h.step()
    assert h.phases()["HS"] == "mit"
    assert h.command("safmod") == "ssmon" and h.command("notif") == "leaveArea"
    h.step(safmod="ssmon", rngDet="close")  # closer, but the robot does not weld: still HS only
    assert h.phases() == {"HRW": "inact", "HS": "mit", "HC": "inact"}
    h.step(rngDet="near")
    assert h.phases()["HS"] == "mit"
    h.step(rngDet="far")
    assert h.phases()["HS"] == "res"
    assert h.command("safmod") == "normal" and h.command("notif") == "ok"
    h.step()
    assert h.phases()["HS"] == "inact"


def test_HC_stop_then_start_over_by_exchanging_the_workpiece():
    h = Harness().step(ract="welding", wact="welding", rngDet="close")
    assert h.phases()["HC"] == "act"
    h.step()
    assert h.phases()["HC"] == "mit"
    assert (h.command("safmod"), h.command("ract"), h.command("wact"), h.command("notif")) == ("stopped", "off", "off", "leaveArea")
    h.step(safmod="stopped", ract="off", wact="off")
    assert h.phases()["HC"] == "mit"
    h.step(rngDet="far")
    assert h.phases()["HC"] == "res"
    assert h.command("ract") == "exchWrkp" and h.command("safmod") == "normal" and h.command("wact") is None
    h.step(safmod="normal")  # the robot has not restarted yet
    assert h.phases()["HC"] == "res"
    h.step(ract="exchWrkp")
    assert h.phases()["HC"] == "inact"
    assert h.command("ract") is None


def test_most_restrictive_demand_wins():
    h = Harness().step(rngDet="near", ract="welding", wact="welding")  # HS
    h.step()
    h.step(safmod="ssmon", rngDet="close")  # HC while HS is mitigated
    h.step()
    assert h.phases()["HS"] == "mit" and h.phases()["HC"] == "mit"
    assert h.command("safmod") == "stopped"


def test_HC_mishap_when_the_welder_ignores_the_stop():
    h = Harness().step(ract="welding", wact="welding", rngDet="close")
    h.step()  # mit: wact off demanded, but the welder keeps welding
    steps = 0
    while h.phases()["HC"] != "mis" and steps < 100:
        h.step(safmod="stopped")
        steps += 1
    assert h.phases()["HC"] == "mis"
    assert 0.5 <= steps * h.system.period <= 0.5 + 2 * h.system.period


def test_single_operator_assumption_is_encoded():
    """While HRW is handled, an operator near the welder is not detected (the misuse gap)."""
    h = Harness().step(rloc="sharedTbl", lgtBar=True)
    h.step()
    assert h.phases()["HRW"] == "mit"
    h.step(safmod="pflim", rngDet="near")
    h.step()
    assert h.phases()["HS"] == "inact"


def test_skipping_quiet_periods_changes_nothing():
    """The controller skips a period whose inputs repeat a period that changed nothing.

    A reference controller that never skips (its memory is wiped before every
    period) must produce the same phases and commands on a long random run in
    which inputs mostly hold, as they do in a cell.
    """
    rng = random.Random(11)
    domains = {name: (ctype.domain() if ctype.kind == "enum" else [False, True]) for name, ctype in TYPES.items()}
    fast, reference = Harness(), Harness()
    memory = reference.system.group("settled_on")
    evaluations = []
    timers = fast.system._timers
    fast.system._timers = lambda *args: evaluations.append(1) or timers(*args)
    for _ in range(3000):
        changes = {}
        if rng.random() < 0.08:
            name = rng.choice(sorted(domains))
            changes[name] = rng.choice(domains[name])
        fast.step(**changes)
        reference.context.get_mutable_discrete_state(memory).SetFromVector(np.full(len(TYPES) + 1, np.nan))
        reference.step(**changes)
        assert fast.phases() == reference.phases()
        for command in COMMANDS:
            assert fast.command(command) == reference.command(command)
    assert len(evaluations) < 1000  # the quiet periods were skipped, not evaluated


def test_risk_model_errors_name_file_line_and_key(tmp_path):
    text = RISK_MODEL.read_text().replace("when: not lgtBar", "when: not lgtbar")
    bad = tmp_path / "rm.yaml"
    bad.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_risk_model(bad)
    line = next(i for i, l in enumerate(text.splitlines(), 1) if "not lgtbar" in l)
    assert e.value.line == line and "lgtbar" in e.value.problem and "hazards.HRW.transitions" in e.value.key


@pytest.mark.parametrize("old, new, key, expected", [
    # a macro that refers to itself, even one no guard uses
    ("macros:\n", "macros:\n  loop: loop and lgtBar\n", "macros.loop", "macro cycle: loop -> loop"),
    # a syntax error in a macro no guard uses
    ("macros:\n", "macros:\n  unused: safmod ==== normal\n", "macros.unused", "expected a value of safmod"),
    # a boolean demand, or default, given a number (YAML's 1 is no boolean)
    ("notif_leaveWrkb: true}", "notif_leaveWrkb: 1}", "hazards.HRW.demands.mit.notif_leaveWrkb", "1 is not a value"),
    ("notif_leaveWrkb: {type: bool, default: false}", "notif_leaveWrkb: {type: bool, default: 0}",
     "controlled.notif_leaveWrkb.default", "0 is not a value"),
])
def test_a_risk_model_broken_where_no_guard_looks_is_refused_at_the_key(tmp_path, old, new, key, expected):
    text = RISK_MODEL.read_text()
    assert old in text
    bad = tmp_path / "rm.yaml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as e:
        load_risk_model(bad)
    assert e.value.key == key and expected in str(e.value) and e.value.line is not None, (e.value.key, str(e.value))


SSM_MODEL = """
name: ssm
monitored:
  sep: {type: number, unit: m}
  safmod: {values: [normal, ssmon, stopped, unknown]}
controlled:
  safmod: {values: [normal, ssmon, stopped], default: normal}
macros:
  moving: safmod in {normal, ssmon, unknown}
hazards:
  CLOSE:
    transitions:
      - {phase: inact, to: act, when: moving and sep < 1.0}
      - {phase: act, to: mit}
      - {phase: mit, to: inact, when: sep >= 1.5}
    demands:
      mit: {safmod: ssmon}
  CONTACT:
    transitions:
      - {phase: inact, to: act, when: sep <= 0.2}
      - {phase: act, to: mit}
      - {phase: mit, to: inact, when: sep > 0.5}
    demands:
      mit: {safmod: stopped}
"""


def _ssm_harness(tmp_path):
    from cellsim.channels import number_type

    path = tmp_path / "ssm.yaml"
    path.write_text(SSM_MODEL)
    types = {"sep": number_type("m"), "safmod": enum_type(SafetyMode)}
    h = Harness.__new__(Harness)
    h.system = SafetyController("sc", 0.02, load_risk_model(path), types, {"safmod": enum_type(SafetyMode)})
    h.context = h.system.CreateDefaultContext()
    h.t, h.inputs = 0.0, {"sep": 3.0, "safmod": "normal"}
    return h


def _phase(h, hazard):
    from cellsim.vocabulary import HazardPhase

    return HazardPhase.from_code(h.phase(hazard)).value


def test_speed_and_separation_monitoring_reads_a_measured_distance(tmp_path):
    h = _ssm_harness(tmp_path)
    h.step(sep=1.2).step()
    assert _phase(h, "CLOSE") == "inact"
    h.step(sep=0.99).step()
    assert _phase(h, "CLOSE") == "mit"
    assert SafetyMode.from_code(h.system.GetOutputPort("safmod").Eval(h.context)[0]).value == "ssmon"
    h.step(sep=0.15).step()
    assert _phase(h, "CONTACT") == "mit"  # the most restrictive demand wins
    assert SafetyMode.from_code(h.system.GetOutputPort("safmod").Eval(h.context)[0]).value == "stopped"
    h.step(sep=1.6).step().step()
    assert (_phase(h, "CLOSE"), _phase(h, "CONTACT")) == ("inact", "inact")


def test_a_separation_with_no_value_compares_false(tmp_path):
    h = _ssm_harness(tmp_path)
    h.step(sep=float("nan")).step()
    # neither sep < 1.0 nor sep <= 0.2 holds for "no value"
    assert (_phase(h, "CLOSE"), _phase(h, "CONTACT")) == ("inact", "inact")


@pytest.mark.parametrize(
    "edit, expected",
    [
        (("sep: {type: number, unit: m}", "sep: {type: number, values: [a]}"), "a number variable has no values list"),
        (("sep: {type: number, unit: m}", "sep: {type: bool, unit: m}"), "only a number variable has a unit"),
        (("safmod: {values: [normal, ssmon, stopped], default: normal}", "safmod: {type: number}"), "numbers are monitored only"),
        (("{phase: act, to: mit}", "{phase: act, to: mitigated}"), "'mitigated' is not a phase of this model"),
        (("      mit: {safmod: ssmon}", "      done: {safmod: ssmon}"), "'done' is not a phase of this model"),
        (("hazards:\n", "phases: {values: [a, b], initial: c}\nhazards:\n"), "'c' is not one of the phases"),
    ],
)
def test_number_variables_and_phases_are_checked(tmp_path, edit, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(SSM_MODEL.replace(*edit, 1))
    with pytest.raises(ConfigError, match=expected):
        load_risk_model(path)


@pytest.mark.parametrize(
    "channel, expected",
    [("ground_truth.separation", None), ("robot.tool_speed", "sep is in m but the channel is in m/s"),
     ("light_barrier.broken", "sep is a number but the channel carries bool")],
)
def test_a_number_variable_is_bound_to_a_number_channel_in_its_unit(tmp_path, channel, expected):
    import shutil

    from cellsim.scenario import load_scenario
    from cellsim.diagrams.cell import build_cell

    folder = tmp_path / "scenario"
    shutil.copytree(ROOT / "scenarios", folder)
    model = folder / "welding_cell_risk_model.yaml"
    model.write_text(model.read_text().replace("  lgtBar: {type: bool}\n", "  lgtBar: {type: bool}\n  sep: {type: number, unit: m}\n", 1))
    scenario = folder / "welding_cell.yaml"
    text = scenario.read_text()
    assert "      lgtBar: light_barrier.broken\n" in text
    scenario.write_text(text.replace("      lgtBar: light_barrier.broken\n", f"      lgtBar: light_barrier.broken\n      sep: {channel}\n", 1))
    sf = load_scenario(scenario)
    if expected is None:
        build_cell(sf, seed=0, duration=1.0, record=False)
    else:
        with pytest.raises(ConfigError, match=expected):
            build_cell(sf, seed=0, duration=1.0, record=False)


def test_a_risk_model_declares_its_own_phases(tmp_path):
    text = SSM_MODEL.replace("hazards:\n", "phases: {values: [clear, warned, slowed, harmed], initial: clear, mishap: harmed}\nhazards:\n", 1)
    text = text.replace("phase: inact", "phase: clear").replace("to: inact", "to: clear")
    text = text.replace("to: act", "to: warned").replace("phase: act", "phase: warned")
    text = text.replace("to: mit", "to: slowed").replace("phase: mit", "phase: slowed").replace("      mit: {", "      slowed: {")
    path = tmp_path / "own.yaml"
    path.write_text(text)
    from cellsim.channels import number_type

    system = SafetyController("sc", 0.02, load_risk_model(path), {"sep": number_type("m"), "safmod": enum_type(SafetyMode)},
                              {"safmod": enum_type(SafetyMode)})
    spec = next(spec for spec, _ in system.channels if spec.signal == "CLOSE")
    assert spec.type.domain() == ["clear", "warned", "slowed", "harmed"]
    context = system.CreateDefaultContext()
    for sep in (0.5, 0.5):
        system.monitored_port.FixValue(context, system.encode_monitored({"sep": sep, "safmod": "normal"}))
        context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context))
    assert system.phases[int(system.GetOutputPort("CLOSE").Eval(context)[0])] == "slowed"




OVERLAPPING = """
name: overlapping
monitored:
  sep: {type: number, unit: m}
controlled:
  safmod: {values: [normal, ssmon, stopped], default: normal}
phases:
  values: [clear, near, close, gone]
  initial: clear
  mishap: gone
hazards:
  H:
    transitions:
      # both guards hold below 0.5 m: the first listed wins
      - {phase: clear, to: close, when: sep < 0.5}
      - {phase: clear, to: near, when: sep < 1.0}
      - {phase: near, to: clear, when: sep >= 1.0}
      - {phase: close, to: clear, when: sep >= 1.0}
      # a transition with no guard, listed after a guarded one that holds: still the guarded one
      - {phase: close, to: gone, when: sep < 0.1}
      - {phase: close, to: near}
    demands:
      near: {safmod: ssmon}
      close: {safmod: stopped}
"""


def test_of_transitions_whose_guards_overlap_the_first_listed_wins(tmp_path):
    """docs/risk-model.md: the first listed transition whose guard holds is taken, one per period. The shipped
    models' guards are disjoint, so only a model made to overlap shows the order counts."""
    from cellsim.channels import number_type

    path = tmp_path / "overlapping.yaml"
    path.write_text(OVERLAPPING)
    h = Harness.__new__(Harness)
    h.system = SafetyController("sc", 0.02, load_risk_model(path), {"sep": number_type("m")},
                                {"safmod": enum_type(SafetyMode)})
    h.context, h.t, h.inputs = h.system.CreateDefaultContext(), 0.0, {"sep": 3.0}

    def phase() -> str:
        return h.system.phases[int(h.phase("H"))]

    def safmod() -> str:
        return SafetyMode.from_code(h.system.GetOutputPort("safmod").Eval(h.context)[0]).value

    h.step(sep=3.0)
    assert phase() == "clear"
    h.step(sep=0.4)  # both clear -> close and clear -> near hold
    assert (phase(), safmod()) == ("close", "stopped")
    h.step(sep=0.05)  # close -> gone (guarded, listed first) and close -> near (always) both hold
    assert phase() == "gone"
    h2 = Harness.__new__(Harness)
    h2.system, h2.t, h2.inputs = h.system, 0.0, {"sep": 0.7}
    h2.context = h.system.CreateDefaultContext()
    h2.step(sep=0.7)  # only clear -> near holds
    assert h.system.phases[int(h2.phase("H"))] == "near"


PROBE = """name: probe
monitored:
  sep: {type: number, unit: m}
  mode: {values: [normal, slow, stopped]}
controlled:
  safmod: {values: [normal, ssmon, stopped], default: normal}
  alarm: {type: bool, default: false}
macros:
  close: sep < 1.0
phases:
  values: [clear, near, harm]
  initial: clear
  mishap: harm
hazards:
  H:
    transitions:
      - {phase: clear, to: near, when: close and mode == normal}
      - {phase: near, to: clear, when: sep >= 1.5}
    demands:
      near: {safmod: ssmon, alarm: true}
"""


@pytest.mark.parametrize("old, new, said", [
    ("mode: {values: [normal, slow, stopped]}", "mode: {type: enum}", "4: monitored.mode.values: an enum variable needs its values"),
    ("alarm: {type: bool, default: false}", "alarm: {type: bool, values: [a], default: false}",
     "7: controlled.alarm.values: a bool variable has no values list"),
    ("mode: {values: [normal, slow, stopped]}", "mode: {values: [normal, slow, stopped], unit: m}",
     "4: monitored.mode.unit: only a number variable has a unit"),
    ("values: [clear, near, harm]", "values: []", "11: phases.values: a risk model needs at least one phase"),
    ("values: [clear, near, harm]", "values: [clear, near, near, harm]", "11: phases.values: phases must differ"),
    ("initial: clear", "initial: calm", "12: phases.initial: 'calm' is not one of the phases (clear, near, harm)"),
    ("mishap: harm", "mishap: hurt", "13: phases.mishap: 'hurt' is not one of the phases (clear, near, harm)"),
    ("safmod: {values: [normal, ssmon, stopped], default: normal}", "safmod: {type: number}",
     "6: controlled.safmod.type: a controlled variable is an enum or a bool (numbers are monitored only)"),
    ("default: normal}", "default: fast}", "6: controlled.safmod.default: 'fast' is not a value of safmod"),
    ("alarm: {type: bool, default: false}", "alarm: {type: bool, default: 0}",
     "7: controlled.alarm.default: 0 is not a value of alarm"),
    ("  H:\n", "  sep:\n", "14: hazards: hazard names must differ from variables and macros: sep"),
    ("  H:\n", "  close:\n", "14: hazards: hazard names must differ from variables and macros: close"),
    ("hazards:\n  H:\n", "hazards:\n  sep:\n    transitions: []\n  close:\n",
     "14: hazards: hazard names must differ from variables and macros: close, sep"),
    ("sep < 1.0", "F sep < 1.0", "9: macros.close: in macro 'close' (at 1:1 of its text): temporal operator 'F' is not allowed here"),
    ("sep < 1.0", "sep <", "9: macros.close: in macro 'close' (at 1:6 of its text): sep is numeric: expected a number, "
                           "found end of input"),
    ("{phase: clear, to: near,", "{phase: calm, to: near,",
     "17: hazards.H.transitions.0.phase: 'calm' is not a phase of this model (clear, near, harm)"),
    ("{phase: near, to: clear,", "{phase: near, to: calm,",
     "18: hazards.H.transitions.1.to: 'calm' is not a phase of this model (clear, near, harm)"),
    ("when: sep >= 1.5}", "when: sep >= fast}",
     "18: hazards.H.transitions.1.when: sep is numeric: expected a number, found 'fast'"),
    ("when: sep >= 1.5}", "when: F sep >= 1.5}", "18: hazards.H.transitions.1.when: temporal operator 'F' is not allowed here"),
    ("near: {safmod: ssmon, alarm: true}", "calm: {safmod: ssmon}",
     "20: hazards.H.demands.calm: 'calm' is not a phase of this model (clear, near, harm)"),
    ("near: {safmod: ssmon, alarm: true}", "near: {siren: true}",
     "20: hazards.H.demands.near.siren: 'siren' is not a controlled variable (safmod, alarm)"),
    ("near: {safmod: ssmon, alarm: true}", "near: {safmod: fast}",
     "20: hazards.H.demands.near.safmod: 'fast' is not a value of safmod (normal, ssmon, stopped)"),
    ("near: {safmod: ssmon, alarm: true}", "near: {alarm: 1}", "20: hazards.H.demands.near.alarm: 1 is not a value of alarm (False, True)"),
    ("near: {safmod: ssmon, alarm: true}", "near: {safmod: 2}",
     "20: hazards.H.demands.near.safmod: 2 is not a value of safmod (normal, ssmon, stopped)"),
    # an audit: a value listed twice ranked a controlled one's restrictiveness twice (the less safe demand won)
    ("safmod: {values: [normal, ssmon, stopped], default: normal}",
     "safmod: {values: [stopped, normal, ssmon, stopped], default: normal}",
     "6: controlled.safmod.values: each value once: stopped repeated"),
    ("mode: {values: [normal, slow, stopped]}", "mode: {values: [normal, slow, slow]}",
     "4: monitored.mode.values: each value once: slow repeated"),
    # and a hazard named as a controlled variable ended in Drake's error, exit 1
    ("  H:\n", "  safmod:\n", "14: hazards: hazard names must differ from variables and macros: safmod"),
    ("  sep: {type: number, unit: m}\n", "  sep: {type: number, unit: m}\n  speed: {type: number, unit: m/s}\n",
     "19: hazards.H.transitions.1.when: cannot compare sep (numeric, in m) with speed (numeric, in m/s): the domains differ"),
])
def test_every_problem_of_a_risk_model_is_one_error_naming_its_file_line_and_key(tmp_path, old, new, said):
    assert old in PROBE
    text = PROBE.replace(old, new, 1)
    if "speed" in new:
        text = text.replace("when: sep >= 1.5}", "when: sep >= speed}")
    path = tmp_path / "probe.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_risk_model(path)
    assert str(e.value) == f"{path}:{said}"


def test_the_probe_model_loads_as_written():
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "probe.yaml"
        path.write_text(PROBE)
        model = load_risk_model(path)
    assert model.source == str(path) and model.name == "probe" and model.phases.values == ["clear", "near", "harm"]
    (hazard,) = model.hazards
    assert [(t.phase, t.to, t.text) for t in hazard.transitions] == [
        ("clear", "near", "close and mode == normal"), ("near", "clear", "sep >= 1.5")]
    from cellsim.logic.syntax import parse

    assert hazard.transitions[1].formula == parse("sep >= 1.5", model.vocabulary())  # what verify translates
    assert hazard.demands == {"near": {"safmod": "ssmon", "alarm": True}}
    assert model.vocabulary()["sep"].unit == "m" and model.vocabulary()["H"].values == ("clear", "near", "harm")
    assert model.demand_rank("safmod", "stopped") == 2 and model.macros == {"close": "sep < 1.0"}
    guard = hazard.transitions[0].guard
    assert guard({"sep": 0.5, "mode": "normal", "H": "clear"}) and not guard({"sep": 0.5, "mode": "slow", "H": "clear"})


def _pop(mapping, *keys):
    for key in keys:
        mapping.pop(key)


WELDING_VARIABLES = "safmod, rloc, wact, ract, rngDet, lgtBar, notif, notif_leaveWrkb"


@pytest.mark.parametrize("scenario, edit, key, problem", [
    ("welding_cell.yaml", lambda c: _pop(c.monitors, "lgtBar"), "monitors",
     "the risk model monitors lgtBar: bind them to channels"),
    ("welding_cell.yaml", lambda c: _pop(c.monitors, "lgtBar", "rloc"), "monitors",
     "the risk model monitors lgtBar, rloc: bind them to channels"),
    ("welding_cell.yaml", lambda c: c.monitors.update(speed="robot.tool_speed"), "monitors.speed",
     f"'speed' is not a monitored variable of the risk model ({WELDING_VARIABLES})"),
    ("welding_cell.yaml", lambda c: c.commands.update(alarm=["operator.notification"]), "commands.alarm",
     "'alarm' is not a controlled variable of the risk model (safmod, ract, wact, notif, notif_leaveWrkb)"),
    ("welding_cell.yaml", lambda c: c.commands.update(wact=["welder.activity_requst"]), "commands.wact.0",
     "no command input 'welder.activity_requst'; did you mean 'welder.activity_request'? (inputs are written module.input)"),
    ("welding_cell.yaml", lambda c: c.commands.update(wact=["weldr.activity_request"]), "commands.wact.0",
     "no command input 'weldr.activity_request'; did you mean 'welder.activity_request'? (inputs are written module.input)"),
    ("welding_cell.yaml", lambda c: _pop(c.commands, "wact"), "commands", "controlled variable 'wact' drives no command input"),
    ("welding_cell.yaml", lambda c: c.monitors.update(notif="safety_controller.notiff"), "monitors.notif",
     "'safety_controller.notiff' is not a command of safety_controller"),
    ("welding_cell.yaml", lambda c: c.monitors.update(rngDet="range_detector.rang"), "monitors.rngDet",
     "no channel 'range_detector.rang'; did you mean 'range_detector.range'?"),
    ("welding_cell.yaml", lambda c: c.monitors.update(rngDet="range_detector.distance"), "monitors.rngDet",
     "rngDet takes ['far', 'near', 'close'] but the channel carries number"),
    ("welding_cell.yaml", lambda c: c.monitors.update(lgtBar="robot.safety_mode"), "monitors.lgtBar",
     "lgtBar takes [False, True] but the channel carries ['normal', 'hguid', 'ssmon', 'pflim', 'srmst', 'stopped', 'unknown']"),
    ("welding_cell.yaml", lambda c: c.commands.update(safmod=["robot.safety_mode_request", "process_controller.activity_request"]),
     "commands.safmod.1", "safmod takes ['normal', 'hguid', 'ssmon', 'pflim', 'srmst', 'stopped'] but the channel carries "
                               "['idle', 'exchWrkp', 'welding', 'off', 'unknown']"),
    ("palletising_cell.yaml", lambda c: c.monitors.update(dist="robot.tool_speed"), "monitors.dist",
     "dist is in m but the channel is in m/s"),
    ("palletising_cell.yaml", lambda c: c.monitors.update(dist="press_scanner.field"), "monitors.dist",
     "dist is a number but the channel carries ['free', 'protective', 'warning']"),
    ("palletising_cell.yaml", lambda c: c.monitors.update(curtain="press_scanner.field"), "monitors.curtain",
     "curtain takes [False, True] but the channel carries ['free', 'protective', 'warning']"),
    ("palletising_cell.yaml", lambda c: c.monitors.update(dist="press.cycles_completed"), "monitors.dist",
     "dist is in m but the channel is in no unit"),
    ("welding_cell.yaml", lambda c: c.commands.update(wact=["welder.physical_sample"]), "commands.wact.0",
     "'welder.physical_sample' is not a command input"),
    ("welding_cell.yaml", lambda c: c.commands.update(wact=["welder.activity_request", "process_controller.activity_request"]),
     "commands.wact.1", "'process_controller.activity_request' expects a different type than the other inputs of wact"),
    # an input the process already drives: one error at the key, where Drake's own check stopped the build in C++
    ("welding_cell.yaml", lambda c: c.commands.update(ract=["process_controller.activity_request", "robot.activity"]),
     "commands.ract.1", "'robot.activity' is already driven by another module of the cell: an input has one driver"),
])
def test_a_risk_model_bound_to_the_wrong_channels_or_inputs_is_one_error_at_its_key(scenario, edit, key, problem):
    """The controller's binding of the risk model's variables to the cell's channels and command inputs, each
    mismatch one error naming the scenario's key and line (the line the key is written on, read from the file: a key
    the edit added names the line of the mapping it went into)."""
    from cellsim.scenario import load_scenario
    from cellsim.diagrams.cell import build_cell

    sf = load_scenario(ROOT / "scenarios" / scenario)
    edit(sf.scenario.behaviours["safety_controller"])
    with pytest.raises(ConfigError) as e:
        build_cell(sf, seed=0, duration=1.0, record=False)
    line = _line_of(ROOT / "scenarios" / scenario, ["behaviours", "safety_controller", *key.split(".")])
    assert (e.value.source, e.value.key, e.value.line, e.value.problem) == (
        str(ROOT / "scenarios" / scenario), f"behaviours.safety_controller.{key}", line, problem)


def _line_of(path, keys: list[str]) -> int:
    """The line (from 1) a key path is written on in the YAML file ``path``, found by its indentation: a list index
    is its list's line (the shipped files write these lists inline), and a key the file does not have is the line
    of the deepest one it has."""
    lines = path.read_text().splitlines()
    line, indent, start = 0, -1, 0
    for key in (k for k in keys if not k.isdigit()):
        child = None  # the indentation of the mapping's own keys
        for i in range(start, len(lines)):
            stripped = lines[i].lstrip()
            depth = len(lines[i]) - len(stripped)
            if not stripped or stripped.startswith("#"):
                continue
            if depth <= indent:
                return line + 1  # out of the mapping: the key is not in the file
            child = depth if child is None else child
            if depth == child and stripped.startswith(f"{key}:"):
                line, indent, start = i, depth, i + 1
                break
        else:
            return line + 1
    return line + 1


TOGGLE = """
name: toggle
monitored:
  sep: {type: number, unit: m}
  mode: {values: [normal, slow, stopped]}
controlled:
  safmod: {values: [normal, ssmon, stopped], default: normal}
  alarm: {type: bool}
phases:
  values: [clear, near, held, harm]
  initial: clear
  mishap: harm
hazards:
  H:
    transitions:
      - {phase: clear, to: near, when: sep < 1.0}
      - {phase: near, to: clear, when: sep >= 1.5}
      - {phase: clear, to: held, when: mode == stopped, after: 0.125}
      - {phase: held, to: clear, when: mode != stopped}
    demands:
      near: {safmod: ssmon, alarm: true}
"""


def _toggle(tmp_path, period: float = 0.03125):
    from cellsim.channels import number_type

    path = tmp_path / "toggle.yaml"
    path.write_text(TOGGLE)
    model = load_risk_model(path)
    mode = enum_type(CodedEnum("mode", [(n, n) for n in ("normal", "slow", "stopped")]))
    h = Harness.__new__(Harness)
    h.system = SafetyController("sc", period, model, {"sep": number_type("m"), "mode": mode},
                                {"safmod": enum_type(SafetyMode), "alarm": BOOL})
    h.context, h.t, h.inputs = h.system.CreateDefaultContext(), 0.0, {"sep": 3.0, "mode": "normal"}
    return h, model


def _h(h) -> str:
    return h.system.phases[int(h.phase("H"))]


def test_inputs_that_return_to_an_earlier_value_still_move_the_phase_the_new_phase_allows(tmp_path):
    """The controller skips a period whose inputs are those of a period that changed nothing; inputs that come back
    after a change are not such a period (the phases moved meanwhile)."""
    h, _ = _toggle(tmp_path)
    h.step(sep=3.0).step(sep=3.0)  # settled: nothing to do
    assert _h(h) == "clear"
    h.step(sep=0.5)
    assert _h(h) == "near"
    h.step(sep=3.0)  # the settled period's inputs again: now near -> clear holds
    assert _h(h) == "clear"


def test_a_timed_transition_fires_when_its_guard_has_held_exactly_its_time(tmp_path):
    """after: 0.125 s at periods of 1/32 s (binary fractions, exact): held from the first period it holds, it fires on
    the fifth, 0.125 s later, not one period late."""
    h, _ = _toggle(tmp_path)
    h.step(mode="stopped")  # t = 0: the guard holds from now
    for _ in range(3):
        h.step()
        assert _h(h) == "clear"
    h.step()  # t = 0.125
    assert _h(h) == "held"


def test_an_enumeration_code_outside_its_values_reads_as_no_value(tmp_path):
    """A monitored enum's code of -1 (no value) or past its values reads as no value, which no comparison matches
    (not the last value, which -1 would index)."""
    h, _ = _toggle(tmp_path)
    for code in (-1.0, 3.0):
        h.system.monitored_port.FixValue(h.context, np.array([3.0, code]))
        for _ in range(6):  # longer than the after: 0.125 of mode == stopped
            h.context.SetTime(h.t)
            h.context.SetDiscreteState(h.system.EvalUniquePeriodicDiscreteUpdate(h.context))
            h.t += h.system.period
        assert _h(h) == "clear", code


def test_the_controllers_ports_channels_and_commands_as_its_users_see_them(tmp_path):
    from cellsim.channels import NO_VALUE

    h, model = _toggle(tmp_path)
    assert h.system.risk_model is model
    assert h.system.GetInputPort("monitored").size() == 2
    specs = {spec.signal: spec for spec, _ in h.system.channels}
    assert specs["H"].description == "Phase of hazard H" and specs["safmod"].description == "Commanded safmod"
    assert specs["alarm"].description == "Commanded alarm"
    h.step()
    alarm = h.system.GetOutputPort("alarm").Eval(h.context)
    assert list(alarm) == [NO_VALUE]  # a bool with no default and no demand: no request, not false
    h.step(sep=0.5)
    assert list(h.system.GetOutputPort("alarm").Eval(h.context)) == [1.0]
    assert h.command("safmod") == "ssmon"


def test_a_bool_command_returns_to_no_request_when_no_hazard_demands_it(tmp_path):
    from cellsim.channels import NO_VALUE

    h, _ = _toggle(tmp_path)
    h.step(sep=0.5)
    assert list(h.system.GetOutputPort("alarm").Eval(h.context)) == [1.0]
    h.step(sep=3.0)  # clear again: the alarm's demand is gone, and it has no default
    assert _h(h) == "clear" and list(h.system.GetOutputPort("alarm").Eval(h.context)) == [NO_VALUE]
    assert h.system.hazard_phases() == {"sc.H": {"initial": "clear", "mishap": "harm"}}


def test_a_missing_risk_model_is_an_error_at_its_key_when_the_scenario_loads(tmp_path):
    from cellsim.scenario import load_scenario

    with pytest.raises(ConfigError) as e:
        load_scenario(ROOT / "scenarios" / "welding_cell.yaml", [f"safety_controller.risk_model={tmp_path / 'none.yaml'}"])
    assert e.value.key == "behaviours.safety_controller.risk_model" and "none.yaml" in e.value.problem


def test_the_controller_is_the_cells_module_of_its_name_and_the_recorder_taps_it():
    from cellsim.scenario import load_scenario
    from cellsim.diagrams.cell import build_cell

    cell = build_cell(load_scenario(ROOT / "scenarios" / "welding_cell.yaml"), seed=0, duration=1.0, record=True)
    assert isinstance(cell.modules["safety_controller"], SafetyController)
    assert cell.recorder.name == "blackbox"
    logs = [system.get_name() for system in cell.diagram.GetSystems() if system.get_name().startswith("blackbox.log")]
    assert logs and cell.diagram.HasSubsystemNamed("safety_controller.monitors")  # a log per period of the channels


def test_what_the_initial_phases_demand_is_commanded_from_the_start_as_verify_models_it(tmp_path):
    """An audit found a hazard's initial phase's demand ignored by the twin until some phase changed (it commanded the
    default, normal, while its initial 'unverified' demanded stopped), where verify's model commands it from the
    start: a 'holds' resting on it would not be the twin's. Both now command it from t = 0."""
    from cellsim.verify.risk import risk_modules

    path = tmp_path / "unverified.yaml"
    path.write_text("""name: unverified
monitored:
  ok: {type: bool}
controlled:
  safmod: {values: [normal, ssmon, stopped], default: normal}
phases: {values: [unverified, inact, act, mis], initial: unverified, mishap: mis}
hazards:
  H:
    transitions:
      - {phase: unverified, to: inact, when: ok}
      - {phase: inact, to: act, when: not ok}
    demands:
      unverified: {safmod: stopped}
      act: {safmod: stopped}
""")
    model = load_risk_model(path)
    system = SafetyController("sc", 0.02, model, {"ok": BOOL}, {"safmod": enum_type(SafetyMode)})
    context = system.CreateDefaultContext()
    commanded = lambda: SafetyMode.from_code(system.GetOutputPort("safmod").Eval(context)[0]).value  # noqa: E731
    assert commanded() == "stopped"  # before any update
    system.monitored_port.FixValue(context, system.encode_monitored({"ok": False}))
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context))
    assert commanded() == "stopped"  # not verified yet: still stopped
    system.monitored_port.FixValue(context, system.encode_monitored({"ok": True}))
    context.SetDiscreteState(system.EvalUniquePeriodicDiscreteUpdate(context))
    assert commanded() == "normal"  # verified: the default
    # verify's model: the command a function of the phases, the initial one's demand included
    formula = next(f for name, f in risk_modules(model, 0.02).formulas.items() if "safmod" in name)
    assert "H = 0" in formula and system.commanded(["unverified"]) == {"safmod": "stopped"}


def test_a_monitored_channel_value_the_risk_model_does_not_list_is_refused_at_its_key(tmp_path):
    """An audit found a risk model without 'unknown' in safmod accepted: a stale robot's 'unknown' then made every guard
    on it false, which read as no hazard (HS inactive, the arm commanded normal, where the shipped model mitigates).
    A value the channel carries and the model does not list is one error at the monitor's key."""
    from cellsim.diagrams.cell import build_cell
    from cellsim.scenario import load_scenario

    text = RISK_MODEL.read_text()
    listed = "safmod: {values: [normal, hguid, ssmon, pflim, srmst, stopped, unknown]"
    assert listed in text
    model = tmp_path / "no_unknown.yaml"
    model.write_text(text.replace(listed, "safmod: {values: [normal, hguid, ssmon, pflim, srmst, stopped]").replace(
        "permissive: safmod in {normal, hguid, ssmon, pflim, unknown}", "permissive: safmod in {normal, hguid, ssmon, pflim}"))
    sf = load_scenario(ROOT / "scenarios" / "welding_cell.yaml", [f"behaviours.safety_controller.risk_model={model}"])
    with pytest.raises(ConfigError) as e:
        build_cell(sf, seed=0, duration=1.0, record=False)
    assert e.value.key == "behaviours.safety_controller.monitors.safmod"
    assert "also carries unknown, which the risk model's safmod does not list" in e.value.problem
