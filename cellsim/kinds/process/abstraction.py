"""The process controller in the abstract cell: its steps, exactly as it takes them.

Per period, as ``cellsim.kinds.process.system`` does: a new activity request listed
in ``restart_on_request`` restarts the steps from the one it names; any other
request pauses them (the robot holds and reports the requested activity);
otherwise, unless the robot stands still (srmst, stopped, unknown), the step
goes on: a move ends when the robot rests at its pose, a dwell after its
seconds, a machine started once it is busy, a wait once it is not, a
``wait_until`` once its condition holds (translated exactly, over the
channels' abstractions), an operation once the machine has worked its seconds. Seconds count in periods of
the safety controller, rounded up.
"""

from __future__ import annotations

import math

from cellsim.kinds.process.system import STANDSTILL
from cellsim.channels import NO_VALUE
from cellsim.logic.syntax import variables_of
from cellsim.verify.expressions import thresholds_of, to_prism
from cellsim.verify.model import ModuleAbstraction, CODE, AbstractCell, lookup, runs_of, set_of, updates_in
from cellsim.verify.prism import Command, Module, Var


class ProcessAbstraction(ModuleAbstraction):
    def declare(self, cell: AbstractCell) -> None:
        """Reads the robot's mode and pose, its machines' busy or activity (in ``build``), and the
        channels its wait_until conditions read (numbers keep their constants apart)."""
        formulas = [c.formula for c in self.system.conditions if c is not None]
        for formula in formulas:
            for channel in sorted(variables_of(formula)):
                cell.read(channel, f"{self.name} (waiting until {channel} ...)")
                if self.system.condition_reads[channel][1].kind == "number":
                    cell.compares(channel, thresholds_of(formulas, channel).values)

    def build(self, cell: AbstractCell) -> None:
        p, system, cfg = self.name, self.system, self.cfg
        period = cell.period * cell.every(p)  # (its own: its counters advance at its updates)
        steps = system.steps
        n = len(steps)
        step, progress, last = f"{p}_step", f"{p}_progress", f"{p}_request"
        request = cell.input(p, "activity_request")
        mode = cell.input(p, "robot_safety_mode")
        reached = cell.input(p, "robot_reached_pose")
        busy = {m: f"({cell.input(p, f'{m}_busy')})" for m in cfg.cycled}
        works = {m: cell.input(p, f"{m}_activity") for m in cfg.operated}
        commands_of = {m: f"{p}_{m}_command" for m in system.machines}
        timed = self.timed(cell)
        durations = [self._periods(s, period, timed) for s in steps]
        most = max([1, *durations])
        restart = system.restart  # request code -> step index
        keys = sorted(restart)
        robot_activities = len(cell.cell.modules[cfg.robot].activity_type)  # a request is one of them, or -1
        paused = f"({request} != -1 & !{set_of(request, keys)})"
        still = set_of(mode, sorted(int(c) for c in STANDSTILL))
        restarting = {e: f"({request} != {last} & {set_of(request, [k for k in keys if restart[k] == e])})"
                      for e in sorted(set(restart.values()))}
        none = f"!({request} != {last} & {set_of(request, keys)})" if keys else "true"
        commands = []
        for s in range(n):
            for e, guard in [(None, none), *restarting.items()]:
                index = s if e is None else e
                prog0 = progress if e is None else "0"
                st = steps[index]
                nxt = (index + 1) % n
                cmds = {m: "false" for m in system.machines}
                if st.move_to is not None:
                    done = f"({reached} = {int(system.targets[index]) + 1})"
                    after = "0"
                elif st.dwell > 0:
                    done = f"({prog0} + 1 >= {durations[index]})"
                    after = f"min({prog0} + 1, {most})"
                elif st.start is not None:
                    done = busy[st.start]
                    after = "0"
                    cmds[st.start] = f"!{done}"
                elif st.wait_for is not None:
                    done = f"!{busy[st.wait_for]}"
                    after = "0"
                elif st.wait_until is not None:
                    formula = system.conditions[index].formula
                    channels = sorted(variables_of(formula))
                    done = "(" + to_prism(formula, {c: cell.encoding(c) for c in channels},
                                          {c: cell.read(c, p) for c in channels}) + ")"
                    after = "0"
                else:
                    m = st.operate.machine
                    worked = f"min({prog0} + ({works[m]} = {int(system.working[m])} ? 1 : 0), {most})"
                    done = f"({worked} >= {durations[index]})"
                    after = worked
                    cmds[m] = f"!{done}"
                held = f"({paused} | {still})"
                update = {
                    step: f"({held} ? {index} : ({done} ? {nxt} : {index}))",
                    progress: f"({held} ? {prog0} : ({done} ? 0 : {after}))",
                    last: request,
                    **{commands_of[m]: (f"(!{held} & {c})" if c != "false" else "false") for m, c in cmds.items()},
                }
                commands.append(Command(f"{step}={s} & {guard}", (("1", update),)))
                if not timed and (st.dwell > 0 or st.operate is not None):  # it may also take longer
                    longer = dict(update, **{step: str(index), progress: f"({held} ? {prog0} : {after})"})
                    longer.update({commands_of[m]: f"(!{held} & true)" for m, c in cmds.items() if c != "false"})
                    commands.append(Command(f"{step}={s} & {guard}", (("1", longer),)))
        cell.add(Module(p, [
            Var(step, 0, n - 1, 0), Var(progress, 0, most, 0), Var(last, -1, robot_activities - 1, int(NO_VALUE)),
            *(Var(v, boolean=True) for v in commands_of.values()),
        ], commands, comment=f"process {p}: steps {', '.join(s.name for s in steps)}"))
        is_paused = f"({last} != -1 & !{set_of(last, keys)})"
        cell.define(f"{p}.target_pose", encoding=CODE, expr=f"({is_paused} ? -1 : {lookup(step, {i: int(t) for i, t in enumerate(system.targets)}, -1)})")
        cell.define(f"{p}.robot_activity", f"({is_paused} ? {last} : {lookup(step, {i: int(a) for i, a in enumerate(system.activity_codes)}, -1)})", CODE)
        cell.define(f"{p}.step", step)
        for m, var in commands_of.items():
            cell.define(f"{p}.{m}_command", f"({var} ? 1 : 0)", CODE)
        if timed:
            cell.assume(f"{p}'s dwells and operations count whole periods of {period:g} s")
        else:
            cell.assume(f"{p}'s dwells and operations may take any time from one period on")

    def refinement(self, cell: AbstractCell, witness: list[dict]) -> tuple[str, str, int] | None:
        """A witness in which a dwell or an operation ends after fewer of this process's updates than its seconds
        take (the steps' durations not modelled): count them in periods (``<process>:timed``)."""
        key, p = f"{self.name}:timed", self.name
        if self.timed(cell):
            return None
        every, steps, restarts = cell.every(p), self.system.steps, self.system.restart
        period = cell.period * every
        runs = runs_of(witness, f"{p}_step")
        for (s, first, last), (then, _, _) in zip(runs, runs[1:]):
            st = steps[s]
            request = (witness[last].get(f"{p}_request"), witness[last + 1].get(f"{p}_request"))
            if (not (st.dwell > 0 or st.operate is not None) or then != (s + 1) % len(steps)
                    or (request[1] != request[0] and request[1] in restarts)):  # (a restart: not its end)
                continue
            # a restart takes the step's first update in the update that enters it (as the twin's process does)
            now, before = witness[first].get(f"{p}_request"), witness[first - 1].get(f"{p}_request") if first else None
            restarted = first > 0 and now != before and now in restarts
            need, took = self._periods(st, period) - restarted, updates_in(first, last, every)
            if took < need:
                what = "dwell" if st.dwell > 0 else "operation"
                return (key, f"{p}_step leaves step '{st.name}' after {took} of its updates of {period:g} s at "
                             f"{first * cell.period:g}-{(last + 1) * cell.period:g} s; its {what} takes at least "
                             f"{need} ({need * period:g} s)", last + 1)
        return None

    @staticmethod
    def _periods(step, period: float, timed: bool = True) -> int:
        if not timed and (step.dwell > 0 or step.operate is not None):
            return 1  # done from one period on (the command above lets it take longer)
        seconds = step.dwell if step.dwell > 0 else (step.operate.seconds if step.operate else 0.0)
        return math.ceil(seconds / period - 1e-9) if seconds > 0 else 0

