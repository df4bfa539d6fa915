"""How far the spot moves per radian of one joint's following error: the gain behind the
emission supervisor's following check (:mod:`drivers.robot.gate`).

The gate's driver compares each period the measured joints with the commanded ones; their
difference ``dq`` (rad) moves the spot by at most ``sum_j gain_j |dq_j|`` (m), where
``gain_j = |dp/dq_j| + reach |dv/dq_j|`` from the last ray's origin ``p`` and unit
direction ``v`` (the beam Jacobian, by central differences of the numpy trace at the robots'
home) and ``reach`` (m) the longest beam from the last mirror to a target. Near home (the
beam's workspace is a few degrees of mirror tilt) this bounds the first-order spot error.
"""

from __future__ import annotations

import numpy as np

from planner.beam.trace import trace_beam
from planner.model.system import System
from planner.model.transforms import Array

REACH = 1.5  # m: the longest beam from the last mirror to a target the gain allows for
STEP = 1e-6  # rad: finite-difference step


def spot_gain(system: System, robot: str, reach: float = REACH) -> Array:
    """Per joint of ``robot`` (m/rad): the spot displacement bound of one radian of error."""
    q0 = system.home
    offset = 0
    for r in system.robots:
        if r.name == robot:
            break
        offset += r.nq
    n = system.robot(robot).nq
    far = system.world_T_laser[:3, 3] + 1.0  # any point: only the rays are used

    def ray(q: Array) -> tuple[Array, Array]:
        tr = trace_beam(system, q, far)
        return tr.hits[-1], tr.dirs[-1]

    gain = np.empty(n)
    for j in range(n):
        dq = np.zeros_like(q0)
        dq[offset + j] = STEP
        (p1, v1), (p0, v0) = ray(q0 + dq), ray(q0 - dq)
        gain[j] = (np.linalg.norm(p1 - p0) + reach * np.linalg.norm(v1 - v0)) / (2 * STEP)
    return gain
