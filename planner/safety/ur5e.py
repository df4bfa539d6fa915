"""The mirror and mount blocks on a flange; the UR5e link shapes (re-exported).

The UR5e collision capsules and boxes belong to its robot model
(:mod:`planner.model.ur5e`, where their sources are documented); they are re-exported here
for the safety code and its callers.
"""

from __future__ import annotations

from dataclasses import dataclass

from planner.model.collision import BoxSpec, CapsuleSpec, CollisionShapes
from planner.model.ur5e import (
    UR5E_BOXES,
    UR5E_CAPSULES,
    UR5E_LINKS,
    UR5E_SELF_EXCLUDED,
    UR5E_SHAPES,
)

__all__ = [
    "DEFAULT_MIRROR_BLOCKS",
    "UR5E_BOXES",
    "UR5E_CAPSULES",
    "UR5E_LINKS",
    "UR5E_SELF_EXCLUDED",
    "UR5E_SHAPES",
    "BoxSpec",
    "CapsuleSpec",
    "CollisionShapes",
    "MirrorBlocks",
]


@dataclass(frozen=True)
class MirrorBlocks:
    """The mirror plate and its mount as boxes (m).

    The plate is ``size`` (from the robot's :class:`~planner.model.system.Mirror`) by
    ``thickness``, behind the reflective face (mirror frame z in [-thickness, 0] for a flat
    face; a curved one's plate also spans the face's depth). The mount
    is a block of ``mount_width`` x ``mount_width`` on the flange face (flange frame z = 0),
    under the mirror centre, up to ``mount_gap`` below the plate's back (flange frame z). No
    mount is built when the plate's back is closer than ``mount_gap`` + 1 mm to the flange.
    """

    thickness: float = 0.006
    mount_width: float = 0.05
    mount_gap: float = 0.0005


DEFAULT_MIRROR_BLOCKS = MirrorBlocks()
