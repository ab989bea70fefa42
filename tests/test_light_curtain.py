"""The light curtain's restart interlock: tripped from the first break until a reset while clear."""

from __future__ import annotations

import numpy as np

from cellsim.config.typed_yaml import load_text
from cellsim.kinds.light_barrier.system import LightBarrier
from cellsim.kinds.light_barrier.config import LightBarrierConfig

# trusting each sample at once: the interlock is tested here, recovery in test_twin_mode
CURTAIN = "kind: light_barrier\ncenter: [0, 0, 1]\nsize: [0.02, 0.9, 0.7]\ntwin: {mode: shadow, recover_after: 1}\n"


class Curtain:
    """A curtain fed by its physical twin's samples (beams broken or clear), stepped by hand."""

    def __init__(self, interlock: bool):
        cfg = load_text(LightBarrierConfig, CURTAIN + f"restart_interlock: {str(interlock).lower()}\n").value
        self.system = LightBarrier("curtain", cfg)
        self.context = self.system.CreateDefaultContext()
        self.t = 0.0
        if interlock:
            self.system.reset_port.FixValue(self.context, [0.0])

    def step(self, beams: bool, reset: bool | None = None) -> bool:
        s = self.system
        s.physical_sample_port.FixValue(self.context, np.array([self.t, 1.0, 1.0 if beams else 0.0]))
        if reset is not None:
            s.reset_port.FixValue(self.context, [1.0 if reset else 0.0])
        self.context.SetTime(self.t)
        self.context.SetDiscreteState(s.EvalUniquePeriodicDiscreteUpdate(self.context))
        self.t += s.period
        return bool(s.GetOutputPort("broken").Eval(self.context)[0] > 0.5)


def test_without_interlock_it_clears_with_the_beams():
    curtain = Curtain(interlock=False)
    assert curtain.step(beams=True) and not curtain.step(beams=False)


def test_with_interlock_it_stays_tripped_until_a_reset_while_clear():
    curtain = Curtain(interlock=True)
    assert not curtain.step(beams=False)
    assert curtain.step(beams=True)
    assert curtain.step(beams=False)  # the person left: still tripped
    assert curtain.step(beams=True, reset=True)  # a reset while broken does nothing
    assert curtain.step(beams=False, reset=True)  # held reset: no new edge
    assert curtain.step(beams=False, reset=False)  # releasing the button is not a reset
    assert not curtain.step(beams=False, reset=True)  # a fresh press while clear resets it
    assert curtain.step(beams=True, reset=True) and curtain.step(beams=False, reset=True)  # trips again


def test_a_shadowed_interlocked_curtain_with_no_samples_stays_tripped():
    curtain = Curtain(interlock=True)
    s = curtain.system
    s.physical_sample_port.FixValue(curtain.context, np.array([-np.inf, 0.0, 0.0]))
    curtain.context.SetDiscreteState(s.EvalUniquePeriodicDiscreteUpdate(curtain.context))
    assert s.GetOutputPort("broken").Eval(curtain.context)[0] == 1.0


def test_with_interlock_interrupted_says_the_beams_now_while_broken_stays_latched():
    """Issue 23: broken was documented as 'a person is in the beams' but stays true until the reset;
    interrupted is the beams now."""
    curtain = Curtain(interlock=True)
    interrupted = lambda: bool(curtain.system.GetOutputPort("interrupted").Eval(curtain.context)[0] > 0.5)  # noqa: E731
    assert curtain.step(beams=True) and interrupted()
    assert curtain.step(beams=False) and not interrupted()  # latched, the beams clear
    assert not curtain.step(beams=False, reset=True) and not interrupted()
    assert not Curtain(interlock=False).system.HasOutputPort("interrupted")  # without an interlock: broken is the beams
