"""A person's body as named regions: the geometry sensors see and the harm service judges.

Any kind that is a person builds its body from these pieces (the ``operator`` kind does).

The regions are those of a biomechanical limits table (``cellsim/kinds/harm/body_limits.yaml``):
head, face, neck, back (with the shoulders), chest, abdomen, pelvis, upper arms, forearms,
hands, thighs and lower legs. Each is one or a few SceneGraph shapes on one of the person's
two frames:

* ``body``: stands on the floor at the person's position, x forward (the way they face), y to
  their left, z up. The trunk, head, legs and the left arm, hanging, are fixed to it.
* ``arm``: the right arm, from the shoulder, pointing along the frame's -z: hanging at rest,
  swung towards a reach point while reaching. Upper arm, forearm and hand follow each other
  along it.

Sizes come from the person's config (``height``, ``body_radius``: half the trunk's depth and the
half-width of the hips, ``arm_length``: shoulder to fingertip); heights along the body follow
the segment proportions of an adult as fractions of the height (Drillis and Contini, 1966:
knee 0.285, hip 0.530, shoulder 0.818, chin 0.870), the arm is split 0.42 / 0.33 / 0.25 (upper
arm, forearm, hand). A user who needs another body scales these through the config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pydrake.geometry import Box, Capsule, Sphere
from pydrake.math import RigidTransform

REGIONS = ("head", "face", "neck", "back", "chest", "abdomen", "pelvis", "upper_arm", "forearm", "hand", "thigh",
           "lower_leg")
"""The body regions, in the limits table's words (``back`` includes the shoulders)."""
TRUNK = ("back", "chest", "abdomen", "pelvis")
"""The regions that move as one block: a push on one is resisted by whatever another rests against (a chest pushed
back is pinned by the wall the back rests on). A head or a limb turns or bends away instead."""
SKULL = ("head", "face")
"""The head's regions, one block too: a face pushed while the back of the head rests on a machine is pinned."""
NECK = ("neck", *TRUNK, *SKULL)
"""The neck joins the trunk to the skull: pushed, it is pinned by whatever either rests against (a throat pushed back
while the back rests on a wall cannot move away: the spine behind it does not)."""
BLOCKS = (TRUNK, SKULL, NECK)
"""The regions whose pushes are resisted together, each block by what any of its regions rests against (the first
block a region is in is its own); every other region moves alone."""

KNEE, HIP, SHOULDER, CHIN = 0.285, 0.530, 0.818, 0.870
"""Heights of the joints as fractions of the body's height (Drillis and Contini, 1966)."""
WAIST = 0.60
"""Top of the pelvis (fraction of the height)."""
RIBS = 0.72
"""Bottom of the chest, top of the abdomen (fraction of the height)."""
ARM_SEGMENTS = (("upper_arm", 0.42), ("forearm", 0.33), ("hand", 0.25))
"""The arm from the shoulder, as fractions of its length."""
HEAD_RADIUS = 0.11
"""m: the skull's sphere."""
LIMB_RADIUS = {"upper_arm": 0.05, "forearm": 0.04, "hand": 0.045, "thigh": 0.08, "lower_leg": 0.06}
"""m: each limb's capsule radius, for an adult of the default size."""
NECK_RADIUS = 0.06
"""m."""
SKIN = (0.85, 0.65, 0.5, 1.0)
CLOTHES = (0.1, 0.35, 0.8, 1.0)


@dataclass(frozen=True)
class Piece:
    """One shape of a body region: on frame ``frame`` (``body`` or ``arm``) at ``pose`` in it."""

    region: str
    side: str
    """``left``, ``right`` or ``""`` for a region on the body's middle."""
    frame: str
    pose: RigidTransform
    shape: object
    color: tuple

    @property
    def name(self) -> str:
        return f"{self.region}_{self.side}" if self.side else self.region


def reach(body_radius: float, arm_length: float) -> float:
    """How far (m) from the body's vertical axis any of its regions may lie, in any posture: an arm stretched out
    from the shoulder (and the hand's thickness), or the trunk's corner."""
    return max(shoulder_offset(body_radius) + arm_length + LIMB_RADIUS["hand"], math.sqrt(2.0) * body_radius)


def shoulder_offset(body_radius: float) -> float:
    """How far (m) each shoulder joint stands from the body's middle, sideways."""
    return body_radius + 0.06


def body_pieces(height: float, body_radius: float, arm_length: float) -> list[Piece]:
    """The regions of a person ``height`` m tall, trunk ``2 body_radius`` deep, arms ``arm_length`` long."""
    h, r = height, body_radius
    knee, hip, waist, ribs, shoulder, chin = (f * h for f in (KNEE, HIP, WAIST, RIBS, SHOULDER, CHIN))
    scale = h / 1.75  # limbs' thickness with the body's size
    pieces: list[Piece] = []

    def box(region, side, x0, x1, y0, y1, z0, z1, color=CLOTHES):
        pose = RigidTransform([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2])
        pieces.append(Piece(region, side, "body", pose, Box(x1 - x0, y1 - y0, z1 - z0), color))

    def capsule(region, side, frame, x, y, z0, z1, radius, color=CLOTHES):
        length = max(abs(z1 - z0) - 2 * radius, 0.005)
        pieces.append(Piece(region, side, frame, RigidTransform([x, y, (z0 + z1) / 2]), Capsule(radius, length), color))

    # legs: lower legs from the floor to the knee, thighs from the knee to the hip
    for side, y in (("left", 0.45 * r), ("right", -0.45 * r)):
        capsule("lower_leg", side, "body", 0.0, y, 0.0, knee, LIMB_RADIUS["lower_leg"] * scale)
        capsule("thigh", side, "body", 0.0, y, knee, hip + 0.02 * h, LIMB_RADIUS["thigh"] * scale)
    # the trunk: pelvis below the waist, abdomen and chest in front, the back behind
    box("pelvis", "", -0.8 * r, 0.8 * r, -r, r, hip, waist)
    box("abdomen", "", 0.0, 0.9 * r, -0.9 * r, 0.9 * r, waist, ribs)
    box("chest", "", 0.0, r, -r, r, ribs, shoulder)
    box("back", "", -r, 0.0, -r, r, waist, shoulder)
    # the shoulders (region back): a bar across the top of the trunk to each shoulder joint
    side_reach = shoulder_offset(r)
    pieces.append(Piece("back", "", "body", RigidTransform([0.0, 0.0, shoulder]),
                        Box(1.2 * r, 2 * side_reach, 0.08 * scale), CLOTHES))
    capsule("neck", "", "body", 0.0, 0.0, shoulder, chin + 0.02 * h, NECK_RADIUS * scale, SKIN)
    head_radius = HEAD_RADIUS * scale
    head_z = h - head_radius - 0.01 * h
    pieces.append(Piece("head", "", "body", RigidTransform([-0.01 * h, 0.0, head_z]), Sphere(head_radius), SKIN))
    # the face: the front of the head, from the chin to the brow
    box("face", "", 0.35 * head_radius, 1.05 * head_radius, -0.7 * head_radius, 0.7 * head_radius, chin, head_z + 0.3 * head_radius, SKIN)
    # the left arm hangs at the side; the right arm is on its own frame (it reaches)
    z = shoulder - 0.02 * h
    for region, fraction in ARM_SEGMENTS:
        length = fraction * arm_length
        capsule(region, "left", "body", 0.0, side_reach, z - length, z, LIMB_RADIUS[region] * scale,
                SKIN if region == "hand" else CLOTHES)
        z -= length
    z = 0.0
    for region, fraction in ARM_SEGMENTS:
        length = fraction * arm_length
        capsule(region, "right", "arm", 0.0, 0.0, z - length, z, LIMB_RADIUS[region] * scale,
                SKIN if region == "hand" else CLOTHES)
        z -= length
    return pieces
