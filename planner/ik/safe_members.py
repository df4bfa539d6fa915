"""The safety filter of the closed-form family search.

A member (hit points on the incoming beam and the mirrors) fixes the beam polyline, so the
rules that depend on the beam alone (keep-out volumes, the laser aperture, a fixed camera's
lens) reject the whole member at once. The rules that depend on the arms (arm-arm, arm-self,
arm-scene, the beam against every arm part) are tried on the member's first configuration
(nearest the previous one), then on a few alternatives (other mirror rolls and IK branches,
nearest first); the first one that passes wins. A target's search gives up after
:data:`BUDGET` rejections. World frame, metres, radians.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from planner.model.transforms import Array
from planner.safety.model import Safety

if TYPE_CHECKING:
    from planner.ik.search_stats import SearchStats

#: configurations of one member tried after its first one fails an arm rule
ALTERNATIVES = 12
#: safety rejections after which a target's search gives up (bounds the time a target that
#: no member can serve safely costs: ~0.1-0.3 ms per rejection)
BUDGET = 400


def _index_combos(n: int, most: int) -> Iterator[tuple[int, ...]]:
    """Index tuples (one index per robot) other than all zeros, by increasing index sum."""
    count = 0
    for total in range(1, most + 1):
        for combo in itertools.product(range(total + 1), repeat=n):
            if sum(combo) == total:
                yield combo
                count += 1
                if count >= most:
                    return


class MemberSafety:
    """Filters closed-form members through :class:`~planner.safety.model.Safety` rules."""

    def __init__(
        self, safety: Safety, alternatives: int = ALTERNATIVES, budget: int = BUDGET
    ) -> None:
        self.safety = safety
        self.alternatives = alternatives
        self.budget = budget
        laser = safety.system.world_T_laser
        self.p0 = laser[:3, 3].copy()

    def polyline(self, hits: list[Array], target: Array) -> Array:
        """The beam as world points: laser exit, the hit on each mirror, the target."""
        return np.vstack([self.p0, *hits, target])

    def first_safe(
        self,
        q: Array,
        gens: list[Iterator[tuple[Array, Array]]],
        firsts: list[tuple[Array, Array]],
        hits: list[Array],
        target: Array,
        stats: SearchStats,
    ) -> Array | None:
        """``q`` (stacked joints of the member's first configuration) if it passes, else the
        first alternative drawn from ``gens`` (per-robot candidate iterators whose first
        items are ``firsts``) that does; None when none does (rejections in ``stats``) or
        when the search has used up its budget of rejections."""
        if stats.unsafe >= self.budget:
            return None
        P = self.polyline(hits, target)
        bad = self.safety.geometry(P)
        if bad is not None:
            stats.reject(bad)
            return None
        bad = self.safety.configuration(q, P)
        if bad is None:
            return q
        stats.reject(bad)
        pools: list[list[Array]] = [[f[0]] for f in firsts]
        for combo in _index_combos(len(gens), self.alternatives):
            if stats.unsafe >= self.budget:
                return None
            if not all(_fill(pools[i], gens[i], k) for i, k in enumerate(combo)):
                continue
            q2 = np.concatenate([pools[i][k] for i, k in enumerate(combo)])
            bad = self.safety.configuration(q2, P)
            if bad is None:
                return q2
            stats.reject(bad)
        return None


def _fill(pool: list[Array], gen: Iterator[tuple[Array, Array]], k: int) -> bool:
    """Draw from ``gen`` until ``pool`` has an item ``k``; False when it runs out."""
    while len(pool) <= k:
        nxt = next(gen, None)
        if nxt is None:
            return False
        pool.append(nxt[0])
    return True
