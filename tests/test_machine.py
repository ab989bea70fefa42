"""The generic machine kind: named activities, supported safety modes, cycles in parallel with the robot."""

from __future__ import annotations

import numpy as np
import pytest

from cellsim.config.typed_yaml import ConfigError, load_text
from cellsim.kinds.machine.config import MachineConfig
from cellsim.kinds.machine.system import Machine, supported_mode
from cellsim.vocabulary import SafetyMode

PRESS = """
kind: machine
activities: [waiting, pressing, down]
rest: waiting
working: pressing
off: down
cycle_time: 0.2
safety_modes: [normal, srmst, stopped]
period: 0.04
"""


class Press:
    """Steps a machine alone: set inputs, apply one periodic update."""

    def __init__(self, text: str = PRESS):
        self.system = Machine("press", load_text(MachineConfig, text).value)
        self.context = self.system.CreateDefaultContext()
        self.system.physical_sample_port.FixValue(self.context, np.array([-np.inf, 0.0, 0.0, 0.0]))
        self.t = 0.0
        self.set(mode="normal", activity=None, command=0.0)

    def set(self, mode: str, activity: str | None, command: float) -> Press:
        s = self.system
        s.mode_request_port.FixValue(self.context, [float(SafetyMode(mode).code)])
        s.activity_request_port.FixValue(self.context, [-1.0 if activity is None else float(s.activity_type(activity).code)])
        s.command_port.FixValue(self.context, [command])
        return self

    def step(self, n: int = 1) -> Press:
        for _ in range(n):
            self.context.SetTime(self.t)
            self.context.SetDiscreteState(self.system.EvalUniquePeriodicDiscreteUpdate(self.context))
            self.t += self.system.period
        return self

    def read(self) -> tuple[str, str, float]:
        s, c = self.system, self.context
        return (SafetyMode.from_code(s.GetOutputPort("safety_mode").Eval(c)[0]).value,
                s.activity_type.from_code(s.GetOutputPort("activity").Eval(c)[0]).value,
                s.GetOutputPort("cycles_completed").Eval(c)[0] if s.HasOutputPort("cycles_completed") else None)


def test_a_command_starts_one_cycle_that_runs_on_its_own():
    press = Press().step()
    assert press.read() == ("normal", "waiting", 0.0)
    press.set("normal", None, 1.0).step()
    assert press.read()[1] == "pressing"
    press.set("normal", None, 0.0).step(3)  # the command may drop: the stroke goes on
    assert press.read()[1] == "pressing"
    press.step(3)
    assert press.read() == ("normal", "waiting", 1.0)
    press.step(5)
    assert press.read()[2] == 1.0  # no new edge, no new cycle


def test_stopped_abandons_a_cycle_and_a_monitored_stop_pauses_it():
    press = Press().set("normal", None, 1.0).step(2)
    press.set("srmst", None, 1.0).step(10)
    assert press.read() == ("srmst", "waiting", 0.0)  # paused, not finished
    press.set("normal", None, 1.0).step(4)
    assert press.read()[1:] == ("waiting", 1.0)  # resumed and finished
    press.set("normal", None, 0.0).step().set("normal", None, 1.0).step(2)
    press.set("stopped", None, 1.0).step()
    assert press.read()[:2] == ("stopped", "down")
    press.set("normal", None, 1.0).step(10)
    assert press.read()[2] == 1.0  # the abandoned stroke never counts


def test_a_mode_it_does_not_support_becomes_the_next_more_restrictive():
    assert supported_mode(SafetyMode.SPEED_SEPARATION, [SafetyMode.NORMAL, SafetyMode.MONITORED_STOP, SafetyMode.STOPPED]) \
        is SafetyMode.MONITORED_STOP
    press = Press().set("pflim", None, 0.0).step()
    assert press.read()[0] == "srmst"


def test_the_safety_controller_can_request_an_activity():
    press = Press().set("normal", "down", 1.0).step(3)
    assert press.read()[1] == "down"


def test_a_shadowed_machine_without_samples_reports_working_and_unknown():
    text = PRESS + "twin: {mode: shadow}\n"
    press = Press(text).step()
    assert press.read()[:2] == ("unknown", "pressing")


def test_a_welder_like_machine_works_while_commanded():
    press = Press(PRESS.replace("cycle_time: 0.2", "cycle_time: 0")).set("normal", None, 1.0).step(5)
    assert press.read()[1] == "pressing"
    press.set("normal", None, 0.0).step()
    assert press.read()[1] == "waiting"
    # with no cycle it has no cycles to count, nor to be busy with
    assert press.read()[2] is None and not press.system.HasOutputPort("busy")


def test_a_machine_that_ignores_unsupported_requests_stays_normal_but_obeys_a_stop():
    welder = PRESS.replace("cycle_time: 0.2", "cycle_time: 0").replace(
        "safety_modes: [normal, srmst, stopped]", "safety_modes: [normal, stopped]\nunsupported_request: ignore"
    )
    press = Press(welder).set("srmst", None, 1.0).step(3)
    assert press.read()[:2] == ("normal", "pressing")  # srmst is not its business
    press.set("stopped", None, 1.0).step()
    assert press.read()[:2] == ("stopped", "down")
    # the default restricts: srmst becomes its next more restrictive mode, stopped
    press = Press(welder.replace("unsupported_request: ignore", "unsupported_request: restrict")).set("srmst", None, 1.0).step()
    assert press.read()[:2] == ("stopped", "down")


@pytest.mark.parametrize(
    "edit, expected",
    [
        (("working: pressing", "working: stamping"), "'stamping' is not one of its activities"),
        (("off: down", "off: waiting"), "three different activities"),
        (("safety_modes: [normal, srmst, stopped]", "safety_modes: [normal]"), "every machine supports stopped"),
        (("cycle_time: 0.2", "cycle_time: -1"), "out of range"),
    ],
)
def test_bad_machine_configs(edit, expected):
    with pytest.raises(ConfigError, match=expected):
        load_text(MachineConfig, PRESS.replace(*edit))


def test_busy_marks_a_cycle_under_way_and_an_abandoned_one_ends_it():
    press = Press()
    busy = lambda: press.system.GetOutputPort("busy").Eval(press.context)[0]  # noqa: E731
    press.step()
    assert busy() == 0.0
    press.set("normal", None, 1.0).step()
    assert busy() == 1.0
    press.set("srmst", None, 1.0).step(3)
    assert busy() == 1.0  # paused, still under way
    press.set("stopped", None, 1.0).step()
    assert busy() == 0.0  # abandoned: whoever waits is released


def test_a_shadowed_machine_is_busy_while_its_twin_works_and_when_unknown():
    press = Press(PRESS + "twin: {mode: shadow, recover_after: 1}\n")  # each sample trusted at once
    busy = lambda: press.system.GetOutputPort("busy").Eval(press.context)[0]  # noqa: E731
    working, resting = (float(press.system.activity_type(a).code) for a in ("pressing", "waiting"))
    normal = float(SafetyMode.NORMAL.code)
    press.step()
    assert busy() == 1.0  # no sample: assume it works
    press.system.physical_sample_port.FixValue(press.context, np.array([press.t, 1.0, normal, resting]))
    press.step()
    assert busy() == 0.0
    press.system.physical_sample_port.FixValue(press.context, np.array([press.t, 1.0, normal, working]))
    press.step()
    assert busy() == 1.0
