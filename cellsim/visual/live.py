"""The cell's drawn state in Meshcat while it simulates: a LeafSystem beside MeshcatVisualizer.

``CueVisualizer`` has one input port per channel its cues read (named after the
channel, carrying the channel's port vector). A periodic publish event every
``PERIOD`` (10 Hz) decodes them into payload values and draws the cues
(:class:`cellsim.visual.cues.CueDrawer`). Its first publish also points the
camera at the cell and fades see-through fixtures (``cellsim.visual.scene``).

It exists only in a diagram built with a Meshcat: a headless run has no such
system and does no drawing work.
"""

from __future__ import annotations

import time

from pydrake.systems.framework import DiagramBuilder, LeafSystem

from cellsim.visual.cues import CueDrawer, collect
from cellsim.visual.scene import draw_see_through, see_through_fixtures, set_camera

PERIOD = 0.1
"""Seconds between redraws of the cues (10 Hz)."""


class CueVisualizer(LeafSystem):
    """Draws the cues of a cell's modules in Meshcat from their channels.

    Ports:
      <module>.<signal> (input), one per channel the cues read: the channel's
        port vector (see ``cellsim.channels``), decoded by its ChannelType.
    """

    def __init__(self, meshcat, cues, specs: dict, extent, see_through):
        super().__init__()
        self.set_name("cue_visualizer")
        self.drawer = CueDrawer(meshcat, cues)
        self.meshcat, self.extent, self.see_through = meshcat, extent, see_through
        self.specs = {name: specs[name] for name in self.drawer.channels if name in specs}
        self.ports = {
            name: self.DeclareVectorInputPort(name, spec.type.size) for name, spec in self.specs.items()
        }
        self.DeclarePeriodicPublishEvent(PERIOD, 0.0, self._publish)
        self.DeclareForcedPublishEvent(self._publish)

    def setup(self) -> None:
        """Camera, see-through fixtures, then every cue's looks."""
        if self.extent is not None:
            set_camera(self.meshcat, self.extent)
        draw_see_through(self.meshcat, self.see_through)
        self.drawer.setup()

    def values(self, context) -> dict:
        """Every channel the cues read, decoded (as the black box would record it)."""
        return {name: self.specs[name].type.decode(port.Eval(context)) for name, port in self.ports.items()}

    def _publish(self, context):
        if not self.drawer.ready:
            self.setup()
        self.drawer.draw(self.values(context), context.get_time())


def add_cue_visualizer(builder: DiagramBuilder, meshcat, modules: dict, channels: dict, scene_graph, plant, extent):
    """Add a :class:`CueVisualizer` for every module's cues, wired to the channels they read.

    Add it after the MeshcatVisualizer: publishes run in the order systems were
    added, so the geometry the cues fade or hide exists when they first draw.
    """
    cues = collect(modules, scene_graph)
    specs = {name: spec for name, (spec, _) in channels.items()}
    system = builder.AddSystem(CueVisualizer(meshcat, cues, specs, extent, see_through_fixtures(plant, scene_graph)))
    for name, port in system.ports.items():
        builder.Connect(channels[name][1], port)
    return system


POLL = 0.1
"""Seconds between looks at Meshcat's connections."""


def wait_for_browser(meshcat, seconds: float, say) -> bool:
    """Wait up to ``seconds`` for a browser to open Meshcat (saying so); whether one did."""
    if seconds <= 0 or meshcat.GetNumActiveConnections() > 0:
        return meshcat.GetNumActiveConnections() > 0
    say(f"waiting up to {seconds:g} s for a browser to open {meshcat.web_url()} (--meshcat-wait) ...")
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if meshcat.GetNumActiveConnections() > 0:
            return True
        time.sleep(POLL)
    say(f"no browser connected within {seconds:g} s; simulating anyway")
    return False
