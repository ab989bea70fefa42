"""The biomechanical limits table, and the severity of a contact judged against it.

The table (a YAML file naming its source: ``body_limits.yaml`` beside this module, or the
scenario's own) gives per body region the permissible quasi-static force F and pressure,
the factor by which a transient contact may exceed that force (or none: no transient
contact permitted), the region's effective mass m_H and its effective spring constant k.

The permissible relative speed follows the energy-transfer model of ISO/TS 15066, Annex A:
the energy a contact may transfer, F^2 / (2 k), equals the kinetic energy of the two masses'
relative motion, mu v^2 / 2, with mu = 1 / (1/m_H + 1/m_R) the reduced mass::

    v_max = F / sqrt(k mu)

with F the transient force (the quasi-static force times the region's factor) for a transient
contact, where the region can recoil. A quasi-static contact (clamping) pins the region: it cannot
move away, so its effective mass is unbounded and mu is the robot's own, m_R: the arm's whole
kinetic energy goes into the region, against the quasi-static force (cellsim's reading of the
model for a pinned region: with the two-mass mu, a hand pressed onto a table would be allowed five
times the speed). m_R is the robot's effective mass, half its moving links' mass plus its
tooling's (shapes welded to a moving link, as a tool is to the flange) and the payload, which move
with the contact point whole. The contact's severity is ``v_rel / v_max``: above 1, the contact
transfers more than the region may take, and it is harm. A contact with a region where no
transient contact is permitted (the head, the face) is harm at any speed: its severity is
``2 + v_rel / v_max`` (v_max of the quasi-static force, v_rel taken as 0 where the two draw apart),
at least 2 however slowly it happens, and the larger the faster. A quasi-static contact begins as
an impact: its severity is the larger of its own and the transient one's (the quasi-static one is
the larger wherever the table permits transient contact).

Pressure needs the contact's area, which the shapes here do not give: it is in the table for
the user's own analysis, and not judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from cellsim.config.typed_yaml import ConfigError, Loaded, Range, load_file

SHIPPED = Path(__file__).with_name("body_limits.yaml")
"""cellsim's table: the values of ISO/TS 15066 Annex A as published in the literature (see its ``source``)."""

FORBIDDEN = 2.0
"""The least severity of a contact the table permits none of (a transient one with the head or face): harm, however
slowly it happens."""
TRANSIENT, QUASI_STATIC = "transient", "quasi_static"
"""A contact's kind: the region can recoil, or it is pinned against something (clamping)."""


@dataclass
class RegionLimits:
    """One body region's limits (units as written: N, N/cm^2, N/mm, kg)."""

    force: Annotated[float, Range(0.0, 10_000.0, lo_open=True, unit="N")]
    """Permissible quasi-static contact force (N)."""
    pressure: Annotated[float, Range(0.0, 10_000.0, lo_open=True, unit="N/cm^2")]
    """Permissible quasi-static pressure (N/cm^2): listed, not judged (the contact area is unknown)."""
    spring_constant: Annotated[float, Range(0.0, 100_000.0, lo_open=True, unit="N/mm")]
    """The region's effective spring constant k (N/mm)."""
    effective_mass: Annotated[float, Range(0.0, 1_000.0, lo_open=True, unit="kg")]
    """The region's effective mass m_H (kg)."""
    transient_factor: Annotated[float, Range(1.0, 100.0, unit="")] | None
    """The permissible transient force is ``force`` times this; null: no transient contact permitted."""


@dataclass
class BodyLimits:
    """A biomechanical limits table."""

    source: str
    """Where the numbers come from (a standard and its edition, a study, your own measurements)."""
    regions: dict[str, RegionLimits]
    """Body region -> its limits; every region of a person's body must be listed."""


def load_limits(path: str | Path = SHIPPED, regions: tuple[str, ...] = ()) -> Loaded[BodyLimits]:
    """Read a limits table; a ConfigError naming the file, line and key for a bad one or a region it lacks."""
    loaded = load_file(BodyLimits, path)
    table = loaded.value
    if not table.source.strip():
        raise ConfigError(str(path), loaded.line_of("source"), "source", "name where the numbers come from")
    missing = [r for r in regions if r not in table.regions]
    if missing:
        raise ConfigError(str(path), loaded.line_of("regions"), "regions",
                          f"no limits for the body region{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    unknown = [r for r in table.regions if regions and r not in regions]
    if unknown:  # a misspelt row would be read by nobody, and its region judged by nothing
        raise ConfigError(str(path), loaded.line_of(f"regions.{unknown[0]}"), f"regions.{unknown[0]}",
                          f"no body region is called '{unknown[0]}' (the body's regions: {', '.join(regions)})")
    return loaded


def reduced_mass(human: float, robot: float) -> float:
    """mu (kg) of a region of effective mass ``human`` and a robot of effective mass ``robot``."""
    return 1.0 / (1.0 / human + 1.0 / robot)


def permissible_speed(limits: RegionLimits, robot_mass: float, kind: str) -> float:
    """v_max (m/s) of a contact of ``kind`` with the region, for a robot of effective mass ``robot_mass`` (kg):
    a transient one against the reduced mass of the two, a quasi-static one (the region pinned, unable to move away)
    against the robot's mass alone; 0 for a transient contact the table does not permit."""
    if kind not in (TRANSIENT, QUASI_STATIC):
        raise ValueError(f"a contact's kind is {TRANSIENT} or {QUASI_STATIC}, not {kind!r}")
    k = limits.spring_constant * 1000.0  # N/mm -> N/m
    if kind == QUASI_STATIC:
        return limits.force / math.sqrt(k * robot_mass)
    if limits.transient_factor is None:
        return 0.0
    return limits.force * limits.transient_factor / math.sqrt(k * reduced_mass(limits.effective_mass, robot_mass))


def severity(limits: RegionLimits, robot_mass: float, kind: str, speed: float) -> float:
    """How far a contact at relative speed ``speed`` (m/s, towards the region) goes towards the region's
    limit: 1 is the limit, above 1 harm. A contact with a region where the table permits no transient contact (the
    head, the face) is at least 2 at any speed: standing still, or drawing apart (a stopped arm's solver noise reads a
    speed of -1e-7 m/s; a head that stepped into an arm backing away touched it all the same). A quasi-static contact
    (the region pinned) begins as an impact: its severity is the larger of the two kinds'. Elsewhere, drawing apart
    (``speed`` below 0) is 0: nothing is pressed."""
    if kind not in (TRANSIENT, QUASI_STATIC):
        raise ValueError(f"a contact's kind is {TRANSIENT} or {QUASI_STATIC}, not {kind!r}")
    pressing = max(speed, 0.0)
    v_pinned = permissible_speed(limits, robot_mass, QUASI_STATIC)
    v_free = permissible_speed(limits, robot_mass, TRANSIENT)
    impact = FORBIDDEN + pressing / v_pinned if v_free == 0.0 else pressing / v_free
    return max(impact, pressing / v_pinned) if kind == QUASI_STATIC else impact
