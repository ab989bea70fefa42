"""A machine of the cell (a press, a welder, a conveyor), in the cell's own words.

A machine has activities named by the scenario (``[idle, pressing, off]``): a
*rest* activity, a *working* activity and an *off* activity. It works in one of
two ways:

* with a ``cycle_time``: a rising edge of its ``command`` input starts a cycle of
  that many seconds (a press stroke), which runs on its own, in parallel with the
  robot, and counts in ``cycles_completed`` when it ends;
* without (``cycle_time: 0``): it works exactly while ``command`` is on (a
  welder welding while the process controller asks).

Its safety: it supports the ``safety_modes`` listed; a requested mode it does not
support becomes the next more restrictive one it supports (or, with
``unsupported_request: ignore``, leaves it in normal: the welding cell's welder,
which only obeys a stop). In ``stopped`` it is
``off`` (a cycle under way is abandoned); in ``srmst`` it rests and a cycle
under way pauses; the safety controller can also request an activity (rest or
off) outright. In shadow or twin mode with no valid physical sample it fails
safe: it reports its working activity and safety mode ``unknown``.
"""

from __future__ import annotations


from cellsim.channels import BOOL, NO_VALUE, enum_type, number_type
from cellsim.entity import EntitySystem, valid_code
from cellsim.kinds.machine.config import MachineConfig
from cellsim.systems import read_scalar, write_changed
from cellsim.vocabulary import SafetyMode, TwinMode, value_set

_MODES = tuple(SafetyMode)


def supported_mode(request: SafetyMode, supported: list[SafetyMode], unsupported: str = "restrict") -> SafetyMode:
    """The requested mode if supported, else the next more restrictive supported one (or normal, ignoring it)."""
    if unsupported == "ignore" and request not in supported:
        return SafetyMode.NORMAL if SafetyMode.NORMAL in supported else supported[0]
    order = [m for m in _MODES if m is not SafetyMode.UNKNOWN]
    for mode in order[order.index(request):]:
        if mode in supported:
            return mode
    return SafetyMode.STOPPED


class Machine(EntitySystem):
    """A machine's controller side.

    Ports:
      safety_mode_request (input): SafetyMode code from the safety controller.
      activity_request (input): code of one of its activities from the safety controller, -1 for none.
      command (input): 1 while the process controller asks it to work (a rising edge starts a cycle).
      physical_sample (input): [t, link, safety_mode code, activity code].
      safety_mode (channel): its safety mode.
      activity (channel): one of its activities.
      cycles_completed (channel, with a cycle_time): cycles it finished.
      busy (channel, bool, with a cycle_time): a cycle is under way (paused included); a cycle abandoned
        in stopped ends it too, so whoever waits for the cycle is released. Shadowing,
        it follows the physical twin's working activity, and reads busy with no valid sample.
    """

    def __init__(self, module: str, cfg: MachineConfig):
        super().__init__(module, cfg.period, cfg.twin, ("safety_mode", "activity"),
                         ("safety_mode_request", "activity_request", "command"))
        self.cfg = cfg
        self.activity_type = value_set(f"{module}_activity", cfg.activities)
        self.rest, self.working, self.off = (self.activity_type(a).code for a in (cfg.rest, cfg.working, cfg.off))
        # the mode it takes for each requested mode's code, worked out once
        self.mode_table = [  # requested mode (its code) -> the mode it takes
            supported_mode(m, cfg.safety_modes, cfg.unsupported_request) if m is not SafetyMode.UNKNOWN else SafetyMode.STOPPED
            for m in _MODES
        ]
        self.mode_request_port = self.declare_input("safety_mode_request", ctype=enum_type(SafetyMode), default=SafetyMode.NORMAL.code)
        self.activity_request_port = self.declare_input("activity_request", ctype=enum_type(self.activity_type), default=NO_VALUE)
        self.command_port = self.declare_input("command", default=0.0)
        # [cycle seconds left, command as last seen]
        self._cycle = self.declare_state("cycle", [0.0, 0.0])
        self._outputs = [
            self.declare_channel("safety_mode", enum_type(SafetyMode), SafetyMode.NORMAL),
            self.declare_channel("activity", enum_type(self.activity_type), cfg.rest),
        ]
        if cfg.cycle_time > 0:  # only a machine with cycles has cycles to count, or to be busy with
            self._outputs += [
                self.declare_channel("cycles_completed", number_type(None), 0.0),
                self.declare_channel("busy", BOOL, False, description="A cycle is under way (paused included)"),
            ]

    def sample_is_valid(self, sample) -> bool:
        return valid_code(sample[0], SafetyMode) and valid_code(sample[1], self.activity_type)

    def safe_command(self) -> dict[str, float]:
        """Its supervisor lost: stopped, its off activity requested, no work commanded."""
        return {**super().safe_command(), "activity_request": float(self.off), "command": 0.0}

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        mode_request = self.mode_request_port.Eval(context)[0]
        activity_request = self.activity_request_port.Eval(context)[0]
        command = self.command_port.Eval(context)[0]
        published = [read_scalar(context, g) for g in self._outputs]
        cycle = context.get_discrete_state(self._cycle).get_value().tolist()
        left, last_command = cycle
        cycles = published[2] if len(published) > 2 else 0.0
        if view.mode is TwinMode.MODEL:
            mode = self.mode_table[int(mode_request)]
            started = command > 0.5 and last_command <= 0.5
            if self.cfg.cycle_time > 0 and started and left <= 0.0:
                left = self.cfg.cycle_time
            if mode is SafetyMode.STOPPED or activity_request == self.off:
                activity, left = self.off, 0.0  # stopped: a cycle under way is abandoned
            elif mode is SafetyMode.MONITORED_STOP or activity_request == self.rest:
                activity = self.rest  # a cycle under way pauses
            elif self.cfg.cycle_time > 0:
                if left > 0.0:
                    left = max(0.0, left - self.period)
                    activity = self.working
                    if left <= 1e-9:
                        left, cycles = 0.0, cycles + 1
                else:
                    activity = self.rest
            else:
                activity = self.working if command > 0.5 else self.rest
            codes = [float(mode.code), float(activity), cycles, 1.0 if left > 0.0 else 0.0]
        elif view.sample is None:  # unknown physical state: assume it works (busy), mode unknown
            codes = [float(SafetyMode.UNKNOWN.code), float(self.working), cycles, 1.0]
        else:  # the physical machine is busy exactly while it reports its working activity
            codes = [float(view.sample[0]), float(view.sample[1]), cycles, 1.0 if view.sample[1] == self.working else 0.0]
        write_changed(xd, self._outputs, codes[: len(self._outputs)], published)
        if [left, command] != cycle:
            xd.get_mutable_vector(self._cycle).SetFromVector([left, command])


