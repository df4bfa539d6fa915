"""What a path solve returns: joints per sample, the feasible runs and the gaps between them.

Kept apart from :mod:`planner.path.solve` so that the planning post-steps that drop path
samples (:mod:`planner.plan.gaps`) read and rebuild results without importing the solver.
Points in the world frame, lengths in metres, joints in rad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from planner.model.status import Reason
from planner.model.transforms import Array


class PathGap(NamedTuple):
    """Samples ``k0 <= k < k1`` (arc length s0..s1 m, starting at world point ``p``) have no
    valid configuration; ``reason`` says why, ``detail`` gives the evidence."""

    k0: int
    k1: int
    s0: float
    s1: float
    p: Array
    reason: Reason
    detail: str


class PathSegment(NamedTuple):
    """A feasible run of samples ``k0 <= k < k1`` solved by one NLP."""

    k0: int
    k1: int
    status: str  # IPOPT return status, or "warm_start" if the NLP failed and the chain is kept
    iterations: int
    solve_time: float  # s, IPOPT only
    build_time: float  # s, NLP construction (0 when cached)


@dataclass(frozen=True)
class PathResult:
    """Joints per sample (``q``: K x nq, NaN in gaps), per-sample spot error (m) and validity."""

    q: Array
    ok: Array  # (K,) bool
    error: Array  # (K,) m
    arc: Array  # (K,) cumulative arc length of the samples, m
    segments: tuple[PathSegment, ...]
    gaps: tuple[PathGap, ...]
    warm_time: float  # s, chain + seed
    nlp_time: float  # s, build + solve of every segment

    @property
    def complete(self) -> bool:
        return not self.gaps
