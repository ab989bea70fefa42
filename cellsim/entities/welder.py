"""The spot welder and its small safety state machine (paper, Fig. 8).

The welder supports two safety modes: ``normal`` and ``stopped``; a request
for ``stopped`` switches it off, every other requested mode leaves it normal.
Its activity is ``off`` while stopped or while the safety controller requests
off, ``idle`` while requested idle, and otherwise ``welding`` exactly while the
process controller's weld command is on.
"""

from __future__ import annotations

from cellsim.channels import NO_VALUE, enum_type
from cellsim.entities.twin import EntitySystem, valid_code
from cellsim.registry import ModuleKind
from cellsim.scenario import WelderConfig
from cellsim.systems import write_scalar
from cellsim.vocabulary import SafetyMode, TwinMode, WelderActivity

NO_REQUEST = NO_VALUE
"""Code on an activity-request port meaning "no request: let the process decide"."""

_ACTIVITIES = tuple(WelderActivity)


def welder_step(mode_request: SafetyMode, activity_request: WelderActivity | None, weld_command: bool):
    """The welder's (mode, activity) for the given requests: its whole state machine."""
    mode = SafetyMode.STOPPED if mode_request is SafetyMode.STOPPED else SafetyMode.NORMAL
    if mode is SafetyMode.STOPPED or activity_request is WelderActivity.OFF:
        return mode, WelderActivity.OFF
    if activity_request is WelderActivity.IDLE:
        return mode, WelderActivity.IDLE
    return mode, WelderActivity.WELDING if weld_command else WelderActivity.IDLE


class Welder(EntitySystem):
    """A spot welder.

    Ports:
      safety_mode_request (input): SafetyMode code from the safety controller.
      activity_request (input): WelderActivity code from the safety controller, or -1 for none.
      weld_command (input): 1 while the process controller asks for a weld.
      physical_sample (input): [t, valid, safety_mode code, activity code].
      safety_mode (channel): normal or stopped.
      activity (channel): idle / welding / off (wact).
    """

    def __init__(self, module: str, cfg: WelderConfig):
        super().__init__(
            module, cfg.period, cfg.twin, ("safety_mode", "activity"), ("safety_mode_request", "activity_request", "weld_command")
        )
        self.mode_request_port = self.declare_input("safety_mode_request", ctype=enum_type(SafetyMode), default=SafetyMode.NORMAL.code)
        self.activity_request_port = self.declare_input("activity_request", ctype=enum_type(WelderActivity), default=NO_REQUEST)
        self.weld_command_port = self.declare_input("weld_command", default=0.0)
        self._mode = self.declare_channel("safety_mode", enum_type(SafetyMode), SafetyMode.NORMAL)
        self._activity = self.declare_channel(
            "activity", enum_type(WelderActivity), WelderActivity.IDLE, description="Welder activity (wact)"
        )

    def sample_is_valid(self, sample) -> bool:
        return valid_code(sample[0], SafetyMode) and valid_code(sample[1], WelderActivity)

    def update(self, context, xd):
        view = self.consult_physical(context, xd)
        mode_request = self.mode_request_port.Eval(context)[0]
        activity_request = self.activity_request_port.Eval(context)[0]
        weld = self.weld_command_port.Eval(context)[0] > 0.5
        self.write_command(xd, view.mode, lambda: (mode_request, activity_request, weld))
        if view.mode is TwinMode.MODEL:
            request = None if activity_request == NO_REQUEST else _ACTIVITIES[int(activity_request)]
            mode, activity = welder_step(SafetyMode.from_code(mode_request), request, weld)
        elif view.sample is None:  # unknown physical state: assume the hazardous one
            mode, activity = SafetyMode.NORMAL, WelderActivity.WELDING
        else:
            mode, activity = SafetyMode.from_code(view.sample[0]), WelderActivity.from_code(view.sample[1])
        write_scalar(xd, self._mode, mode.code)
        write_scalar(xd, self._activity, activity.code)


KIND = ModuleKind(
    name="welder",
    section="entities",
    config=WelderConfig,
    build=lambda cell, name, cfg: cell.add(name, Welder(name, cfg)),
    summary="A spot welder with safety modes normal and stopped; welds while the process controller asks.",
    sample_fields=("safety_mode", "activity"),
    command_fields=("safety_mode_request", "activity_request", "weld_command"),
    channels=(
        ("safety_mode", "enum", "normal or stopped"),
        ("activity", "enum", "idle / welding / off (wact); welding when shadowing with no valid sample"),
        ("twin_mode", "enum", "model / shadow / twin"),
        ("physical_link", "enum", "unused / ok / stale / corrupt"),
    ),
)
