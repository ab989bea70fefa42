"""The cell in Meshcat: camera, see-through fixtures, and drawn state.

* :mod:`cellsim.visual.cues`: the hooks a module offers (its cues, a sensor's
  sight, how it shows a recorded pose) and the drawer that shows them;
* :mod:`cellsim.visual.scene`: the camera outside the fence, see-through fixtures;
* :mod:`cellsim.visual.live`: a LeafSystem drawing the cues while the cell simulates;
* :mod:`cellsim.visual.replay`: a black box played into a Meshcat recording;
* :mod:`cellsim.visual.serve`: the command-line side (opening Meshcat, waiting for
  the browser, serving until Ctrl-C).

Details and colours: ``docs/meshcat.md``.
"""
