"""Closed-form durations of time-optimal jerk-limited rest-to-rest moves (s).

Used by the visit order (:mod:`planner.path.tour`, its move costs) and the timing
(:mod:`planner.path.timing`); it imports neither.
"""

from __future__ import annotations

import numpy as np

from planner.model.system import Limits
from planner.model.transforms import Array


def rest_to_rest_time(
    d: Array | float, v: Array | float, a: Array | float, j: Array | float
) -> Array:
    """Time-optimal jerk-limited 1-DOF rest-to-rest duration (s) for distances ``|d|``.

    Closed form: cruise at v if reachable; else a peak velocity below v, with or without a
    constant-acceleration phase. Broadcasts over all arguments.
    """
    dist = np.abs(np.asarray(d, dtype=float))
    v, a, j = (np.broadcast_to(np.asarray(x, dtype=float), dist.shape) for x in (v, a, j))
    d = dist
    t_acc = np.where(v * j >= a * a, v / a + a / j, 2 * np.sqrt(v / j))  # 0 -> v
    cruise = d >= v * t_acc
    vp_a = a * (-a / j + np.sqrt((a / j) ** 2 + 4 * d / a)) / 2  # peak with an a-limited phase
    vp_j = (d * np.sqrt(j) / 2) ** (2 / 3)  # peak with jerk phases only
    no_cruise = np.where(vp_a * j >= a * a, 2 * (vp_a / a + a / j), 4 * np.sqrt(vp_j / j))
    return np.where(cruise, d / np.maximum(v, 1e-300) + t_acc, no_cruise)


def move_time(q0: Array, q1: Array, lim: Limits) -> Array:
    """Estimated synchronised move time: the slowest joint's rest-to-rest time (broadcasts
    over leading axes of ``q1 - q0``)."""
    return rest_to_rest_time(q1 - q0, lim.velocity, lim.acceleration, lim.jerk).max(axis=-1)
