"""A recorded run played into Meshcat: Drake's Meshcat recording of a black box.

The cell's geometry is rebuilt from the run's ``scenario.yaml`` (the diagram is
built, never simulated); each module that offers ``show_recorded`` puts its
drawn pose from the recorded channels (a robot's joint positions, a person's
position), MeshcatVisualizer publishes the poses, and the cues
(:mod:`cellsim.visual.cues`) show the recorded state, frame by frame, into a
Meshcat recording. The browser then plays it as an animation with a time slider.

``at`` starts the animation at that moment of the run: the recording covers
``[at, end]``, its time 0 being the run's ``at``; ``speed`` scales its clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FRAME_PERIOD = 0.1
"""Seconds of the run between the frames a replay draws (the black box holds joint positions and positions as
they changed, at their publishers' rates)."""


class ReplayError(Exception):
    """A run that cannot be replayed (the message is one line)."""


@dataclass
class Replay:
    """What was played: the run's end (s), where it started (s), its speed, frames recorded, and the cell drawn."""

    end: float
    at: float
    speed: float
    frames: int
    cell: object


def check_replay(run: str | Path, at: float = 0.0, speed: float = 1.0):
    """The run's black box, its scenario and its end (s), once ``at`` and ``speed`` are known to fit it;
    ReplayError (one line) otherwise. Everything a replay checks, before anything is opened or drawn."""
    from cellsim.blackbox import BlackBox, BlackBoxError
    from cellsim.validation.check import CheckError, locate_rebuildable_run
    from cellsim.blackbox import run_end
    from cellsim.validation.traces import blackbox_domains, checked_values

    if not (math.isfinite(speed) and 0.01 <= speed <= 100.0):
        raise ReplayError(f"--speed {speed:g}: expected from 0.01 to 100 times real time")
    try:
        blackbox, sf = locate_rebuildable_run(run, "replay needs it to rebuild the cell")
    except CheckError as e:
        raise ReplayError(str(e)) from None
    try:
        with BlackBox(blackbox) as bb:
            end, _ = run_end(bb, bb.metadata())
            # every record read as check and export read it: a corrupt one is said now, not once Meshcat is open
            for _ in checked_values(bb, list(bb.channels()), blackbox_domains(bb)):
                pass
            bb.check_vectors()
            bb.check_channels()
    except BlackBoxError as e:
        raise ReplayError(str(e)) from None
    if end <= 0:
        raise ReplayError(f"{blackbox}: the run recorded no time (no duration or recorded_until in its metadata)")
    if not (math.isfinite(at) and 0.0 <= at <= end):
        raise ReplayError(f"--at {at:g}: expected a time from 0 to {end:g} s (the run's end)")
    return blackbox, sf, end


def replay(run: str | Path, meshcat, *, at: float = 0.0, speed: float = 1.0) -> Replay:
    """Record the run in ``run`` (a run folder or its black box) into ``meshcat`` and publish the recording.

    Raises ReplayError (or the scenario's ConfigError) for a missing or corrupt
    run, or ``at`` outside the run.
    """
    from cellsim.blackbox import BlackBox, BlackBoxError
    from cellsim.diagrams.cell import build_cell

    blackbox, sf, end = check_replay(run, at, speed)
    try:
        with BlackBox(blackbox) as bb:
            cell = build_cell(sf, seed=bb.recorded_seed(sf.scenario.seed), duration=end, record=False, meshcat=meshcat)
            bb.check_vector_sizes(cell.vector_sizes())
            wanted = set(cell.cue_visualizer.drawer.channels)
            for name, system in cell.modules.items():
                wanted.update(f"{name}.{signal}" for signal in getattr(system, "replay_channels", ()))
            series = {name: bb.series(name) for name in sorted(wanted) if name in bb.channels()}
    except BlackBoxError as e:
        raise ReplayError(str(e)) from None
    frames = _record(cell, meshcat, series, at, end, speed)
    return Replay(end, at, speed, frames, cell)


def _record(cell, meshcat, series: dict, at: float, end: float, speed: float) -> int:
    """Record frames at the run's times ``at, at + FRAME_PERIOD, ..., end``; returns how many."""
    context = cell.diagram.CreateDefaultContext()
    cell.set_initial_state(context)
    visualizer, cues = cell.meshcat_visualizer, cell.cue_visualizer
    vis_context = visualizer.GetMyContextFromRoot(context)
    showing = [s for s in cell.modules.values() if hasattr(s, "show_recorded")]
    times = np.arange(at, end + 1e-9, FRAME_PERIOD)
    if times[-1] < end - 1e-9:
        times = np.append(times, end)
    meshcat.StartRecording(frames_per_second=speed / FRAME_PERIOD, set_visualizations_while_recording=True)
    for t in times:
        values = {name: s.value_at(t + 1e-9) for name, s in series.items()}
        for system in showing:
            system.show_recorded(cell, context, values)
        context.SetTime((t - at) / speed)  # the recording's clock
        visualizer.ForcedPublish(vis_context)
        if not cues.drawer.ready:
            cues.setup()  # once the geometry exists: camera, see-through fixtures, looks
        cues.drawer.draw(values, context.get_time())
    meshcat.StopRecording()
    meshcat.PublishRecording()
    return len(times)
