"""Beam IK at a PRESCRIBED relay geometry, for the coverage study (docs/conventions.md: Beam model).

Why this is not :mod:`planner.ik`: :meth:`planner.ik.closed_form.ClosedForm.search` chooses
the hit points itself (the first along the laser ray near the previous mirror centre, the
others near the mirrors' current centres) and always uses every robot of its system. The
coverage study instead enumerates relay geometries independently of any target: the hit
points are fixed sites on a shell around the object and the beam may run through any ordered
subset of the robots. So this module only fixes the geometry and delegates the rest to the
closed-form helpers of :mod:`planner.ik.closed_form`: mirror normal = :func:`bisector` of the
arriving and leaving beams, :meth:`planner.model.mirror.Mirror.place` centred on the hit point (the beam hits the
middle of the ROI) with a sampled roll, the UR analytic IK and :func:`pick_branch` (nearest
the robot's home within its joint limits). The spot error of such a solution is at machine
precision.

World frame, metres, radians throughout.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planner.model.system import Robot, System
from planner.model.transforms import Array, inv_T

#: mirror rolls (rad) tried about the normal, and the in-plane reference of roll 0
DEFAULT_SPINS = tuple(np.linspace(0.0, 2 * np.pi, 8, endpoint=False))
X_REF = np.array([1.0, 0.0, 0.0])
_CENTRE = np.zeros(2)


def unit(v: Array) -> Array:
    """``v / |v|`` (no zero check: callers build directions between distinct points)."""
    return v / np.linalg.norm(v)


def chain_system(system: System, robots: Sequence[int]) -> System:
    """The sub-system of ``system``'s ``robots`` (beam order), same laser and camera."""
    return System(system.world_T_laser, tuple(system.robots[i] for i in robots), system.camera)


def laser_ray(system: System) -> tuple[Array, Array]:
    """Origin and unit direction of the laser beam (world)."""
    return system.world_T_laser[:3, 3].copy(), unit(system.world_T_laser[:3, 2].copy())


def mirror_ik(
    robot: Robot,
    hit: Array,
    v_in: Array,
    v_out: Array,
    spins: Sequence[float] = DEFAULT_SPINS,
) -> Array | None:
    """Joints of ``robot`` whose mirror, centred at ``hit``, reflects unit ``v_in`` into unit
    ``v_out``: the first roll in ``spins`` with an analytic IK branch inside the joint limits
    (the branch nearest home), or None (also when ``v_out == v_in``: grazing)."""
    from planner.ik.closed_form import bisector, pick_branch  # heavy: lazy

    n = bisector(v_in, v_out)
    if n is None:
        return None
    base_T_world = inv_T(robot.world_T_base)
    mirror_T_flange = inv_T(robot.mirror.flange_T_mirror)
    for spin in spins:
        world_T_mirror = robot.mirror.place(hit, n, X_REF, float(spin), _CENTRE)
        branches = robot.kinematics.analytic_ik(base_T_world @ world_T_mirror @ mirror_T_flange)
        if not branches:
            continue
        q, _ = pick_branch(np.array(branches), robot.home, robot.limits.lower, robot.limits.upper)
        if q is not None:
            return q
    return None


def solve_chain(
    system: System,
    hits: Sequence[Array],
    target: Array,
    spins: Sequence[float] = DEFAULT_SPINS,
) -> Array | None:
    """Stacked joints relaying the beam through ``hits`` (one per robot of ``system``, in
    order) onto ``target``, or None. ``hits[0]`` must lie on the laser ray."""
    _, v = laser_ray(system)
    points = [*hits, np.asarray(target, dtype=float)]
    qs = []
    for i, robot in enumerate(system.robots):
        v_out = unit(points[i + 1] - points[i])
        q = mirror_ik(robot, points[i], v, v_out, spins)
        if q is None:
            return None
        qs.append(q)
        v = v_out
    return system.stack_q(qs)
