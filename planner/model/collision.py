"""Collision shapes of a robot model: capsules and boxes fixed to its links (metres).

A link index i is the frame of the joint that moves the link (i = 1..nq, the URDF joint
order); link 0 is the fixed robot base frame. :mod:`planner.safety` builds its collision
world from these; :mod:`planner.model.robots` keeps them per robot model.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CapsuleSpec:
    """A capsule ``name`` on link ``link``: segment ``a -> b`` (m, link frame) swept by a
    sphere of ``radius`` (m)."""

    name: str
    link: int
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class BoxSpec:
    """A box ``name`` on link ``link``: centre (m, link frame), full ``extents`` (m) along the
    link frame's axes."""

    name: str
    link: int
    centre: tuple[float, float, float]
    extents: tuple[float, float, float]


@dataclass(frozen=True)
class CollisionShapes:
    """A robot model's link shapes. ``links``: link names in chain order (index 0 the fixed
    base, so ``len(links) - 1`` joints); ``self_excluded``: pairs of shape names never
    checked against each other (their envelopes touch although the real links cannot)."""

    links: tuple[str, ...]
    capsules: tuple[CapsuleSpec, ...]
    boxes: tuple[BoxSpec, ...] = ()
    self_excluded: frozenset[tuple[str, str]] = frozenset()

    @property
    def nq(self) -> int:
        """Number of joints the shapes are made for."""
        return len(self.links) - 1
