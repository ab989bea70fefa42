"""A machine in the abstract cell: its activity, safety mode and cycle, exactly as it updates them.

Per period it takes the requested safety mode (through its table of supported
modes), is off while stopped or asked to be off, rests while in a monitored stop
or asked to rest (a cycle under way pauses), and otherwise works: a cycle
started by a rising edge of its command runs ``cycle_time`` (counted in periods,
rounded up), a machine without a cycle works while commanded.
"""

from __future__ import annotations

import math

from cellsim.verify.model import ModuleAbstraction, AbstractCell, lookup
from cellsim.verify.prism import Command, Module, Var
from cellsim.vocabulary import SafetyMode

_MODES = tuple(SafetyMode)


class MachineAbstraction(ModuleAbstraction):
    def declare(self, cell: AbstractCell) -> None:
        """Reads its three inputs (in ``build``)."""

    def build(self, cell: AbstractCell) -> None:
        m, cfg, system = self.name, self.cfg, self.system
        request = cell.input(m, "safety_mode_request")
        wanted = cell.input(m, "activity_request")
        command = f"({cell.input(m, 'command')} = 1)"
        mode, activity, last = f"{m}_mode", f"{m}_activity", f"{m}_commanded"
        table = {code: system.mode_table[code].code for code in range(len(_MODES))}
        new_mode = lookup(request, table, SafetyMode.STOPPED.code)
        stopped = f"({new_mode} = {SafetyMode.STOPPED.code} | {wanted} = {system.off})"
        resting = f"({new_mode} = {SafetyMode.MONITORED_STOP.code} | {wanted} = {system.rest})"
        variables = [
            Var(mode, 0, len(_MODES) - 1, SafetyMode.NORMAL.code),
            Var(activity, 0, len(cfg.activities) - 1, system.rest),
            Var(last, boolean=True),
        ]
        updates = {mode: new_mode, last: command}
        choices = [updates]
        if cfg.cycle_time > 0:
            own = cell.period * cell.every(m)  # (its counter advances at its own updates)
            n = max(1, math.ceil(cfg.cycle_time / own - 1e-9)) if self.timed(cell) else 1
            left = f"{m}_left"
            variables.append(Var(left, 0, n, 0))
            started = f"({command} & !{last} & {left} = 0 ? {n} : {left})"
            updates[left] = f"({stopped} ? 0 : {resting} ? {started} : max({started} - 1, 0))"
            updates[activity] = (f"({stopped} ? {system.off} : {resting} ? {system.rest} : "
                                 f"{started} > 0 ? {system.working} : {system.rest})")
            cell.define(f"{m}.busy", f"({left} > 0)")
            if self.timed(cell):
                cell.assume(f"{m}'s cycle of {cfg.cycle_time:g} s takes {n} periods")
            else:  # a cycle under way may also go on: any length from one period on
                going = dict(updates, **{left: f"({stopped} ? 0 : {resting} ? {started} : {started})"})
                choices.append(going)
                cell.assume(f"{m}'s cycle may take any time from one period on")
        else:
            updates[activity] = f"({stopped} ? {system.off} : {resting} ? {system.rest} : {command} ? {system.working} : {system.rest})"
        cell.add(Module(m, variables, [Command("true", (("1", u),)) for u in choices],
                        comment=f"machine {m}: activities {', '.join(cfg.activities)}"))
        cell.define(f"{m}.safety_mode", mode)
        cell.define(f"{m}.activity", activity)
