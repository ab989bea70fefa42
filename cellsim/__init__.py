"""cellsim: scenario digital twins of collaborative robot cells, for safety assurance.

A scenario (YAML) describes a cell's layout, its entities (robot, welder, sensors,
operators) with their twin modes, its behaviours (process and safety controllers,
analyses) and its services (recording). ``cellsim.diagrams.cell`` assembles it into a Drake
Diagram; ``cellsim.simulation`` runs it headless and writes a black box.
"""

__version__ = "0.1.0"
