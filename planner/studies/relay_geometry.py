"""Exact beam IK by construction, for the studies (SPEC section 3, paper Eqs. 1-2).

A relay geometry is fixed by the hit points ``h_1..h_k`` (``h_1`` on the laser ray) and the
target: mirror ``i`` must then have its normal along the bisector ``n ∝ v_out − v_in`` (so
``v_out = v_in − 2 (v_in·n) n`` exactly, front face hit), centre at ``h_i`` (the beam hits the
middle of the ROI) and a free spin about ``n``. Each robot then needs the flange pose
``base_T_flange = inv(world_T_base) · world_T_mirror · inv(flange_T_mirror)``, which the
closed-form UR IK solves in microseconds. The spot error of such a solution is at machine
precision, so it is a clean nominal for sensitivity studies and an exact reachability test
for coverage (a sampled search: coverage found this way is a lower bound).

World frame, metres, radians throughout.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planner.system import Robot, System
from planner.transforms import Array, inv_T, make_T

#: default search grids: distance of the first hit along the laser ray (m) and mirror spins
DEFAULT_SPINS = tuple(np.linspace(0.0, 2 * np.pi, 8, endpoint=False))


def unit(v: Array) -> Array:
    """``v / |v|`` (no zero check: callers build directions between distinct points)."""
    return v / np.linalg.norm(v)


def mirror_pose(hit: Array, v_in: Array, v_out: Array, spin: float) -> Array:
    """``world_T_mirror`` centred at ``hit`` that reflects unit ``v_in`` into unit ``v_out``.

    ``spin`` (rad) rotates the mirror's x/y edges about its normal. Raises ValueError when
    ``v_out == v_in`` (grazing: no mirror can do that).
    """
    n = v_out - v_in
    norm = np.linalg.norm(n)
    if norm < 1e-9:
        raise ValueError("v_out equals v_in: a mirror cannot pass the beam straight on")
    n = n / norm
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x0 = unit(np.cross(a, n))
    y0 = np.cross(n, x0)
    x = np.cos(spin) * x0 + np.sin(spin) * y0
    y = np.cross(n, x)
    return make_T(np.column_stack([x, y, n]), hit)


def robot_ik(robot: Robot, world_T_mirror: Array, q_ref: Array | None = None) -> Array | None:
    """Joints placing ``robot``'s mirror at ``world_T_mirror``, inside the joint limits.

    Among the closed-form branches (and their ±2π wraps allowed by the limits) returns the
    one closest to ``q_ref`` (default: the robot's home), or None if none is feasible.
    """
    base_T_flange = inv_T(robot.world_T_base) @ world_T_mirror @ inv_T(robot.mirror.flange_T_mirror)
    sols = robot.kinematics.analytic_ik(base_T_flange)
    if not sols:
        return None
    ref = robot.home if q_ref is None else q_ref
    lo, hi = robot.limits.lower, robot.limits.upper
    best, best_d = None, np.inf
    for q in sols:
        # bring every joint to the wrap nearest the reference, then check limits
        qw = q + 2 * np.pi * np.round((ref - q) / (2 * np.pi))
        for cand in (qw, q):
            if np.all(cand >= lo - 1e-12) and np.all(cand <= hi + 1e-12):
                d = float(np.sum((cand - ref) ** 2))
                if d < best_d:
                    best, best_d = cand, d
                break
    return best


def laser_ray(system: System) -> tuple[Array, Array]:
    """Origin and unit direction of the laser beam (world)."""
    return system.world_T_laser[:3, 3].copy(), unit(system.world_T_laser[:3, 2].copy())


def solve_chain(
    system: System,
    hits: Sequence[Array],
    target: Array,
    spins: Sequence[float] = DEFAULT_SPINS,
) -> Array | None:
    """Stacked joints relaying the beam through ``hits`` (one per robot, in order) to
    ``target``, or None. ``hits[0]`` must lie on the laser ray."""
    _, v = laser_ray(system)
    points = [*hits, np.asarray(target, dtype=float)]
    qs = []
    for i, robot in enumerate(system.robots):
        v_out = unit(points[i + 1] - points[i])
        q = None
        for spin in spins:
            try:
                M = mirror_pose(points[i], v, v_out, spin)
            except ValueError:
                return None
            q = robot_ik(robot, M)
            if q is not None:
                break
        if q is None:
            return None
        qs.append(q)
        v = v_out
    return system.stack_q(qs)


def solve_single(
    system: System,
    target: Array,
    normal: Array | None = None,
    distances: Sequence[float] | None = None,
    spins: Sequence[float] = DEFAULT_SPINS,
    max_incidence: float = np.pi / 2,
) -> Array | None:
    """Exact IK for one robot (N = 1): the mirror centre slides along the laser ray.

    Tries hit distances ``distances`` (m along the laser ray, default 0.1..1.2 m) and spins;
    returns the feasible joints closest to home, or None. With a ``normal`` the arriving
    beam must make at most ``max_incidence`` (rad) with it.
    """
    if system.n_robots != 1:
        raise ValueError(f"solve_single needs one robot, the system has {system.n_robots}")
    robot = system.robots[0]
    p, v = laser_ray(system)
    target = np.asarray(target, dtype=float)
    ds = np.linspace(0.1, 1.2, 23) if distances is None else distances
    best, best_d = None, np.inf
    for d in ds:
        h = p + d * v
        v_out = unit(target - h)
        if normal is not None and np.arccos(min(1.0, abs(float(v_out @ normal)))) > max_incidence:
            continue
        for spin in spins:
            try:
                M = mirror_pose(h, v, v_out, spin)
            except ValueError:
                break
            q = robot_ik(robot, M)
            if q is not None:
                dist = float(np.sum((q - robot.home) ** 2))
                if dist < best_d:
                    best, best_d = q, dist
    return best
