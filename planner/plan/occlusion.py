"""The ``occluded`` post-check of planning: a solved beam must not cross the
scene.

The IK solves the beam as pure geometry; afterwards every segment of each solved beam - laser
exit -> mirror hit 1, hit i -> hit i + 1, last hit -> spot - is raycast against the scene
(:class:`planner.model.scene.SceneModel`, world frame, metres), all targets in one batch. A
surface within ``END_MARGIN`` (1 mm) of a segment's end does not count, so a target lying on
a board is not occluded by that board. A blocked target becomes ``failed`` / ``occluded``
with evidence: the segment (``laser->arm0``, ``arm0->arm1``, ``arm1->target``) and its end
points, the object, the world point where the beam meets it and the blocked configuration.
Point targets first try other members of the closed-form family (the first hit slid along
the incoming beam, :func:`check_points`); path samples become gaps (:func:`check_path`).
An empty scene returns the input untouched; blocked path samples are dropped by the gap
machinery of :mod:`planner.plan.gaps`.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from typing import TYPE_CHECKING

import numpy as np

from planner.beam.trace import beam_vertices, mirror_poses, trace_beam
from planner.ik import Solution
from planner.model.scene import END_MARGIN, START_MARGIN, SceneModel
from planner.model.status import Reason
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.path.result import PathResult
from planner.plan.gaps import SampleGap, failed_with, split_path

if TYPE_CHECKING:
    from planner.ik import BeamIK

#: m, slides of the first mirror's hit along the laser beam tried for an occluded target
RETRY_SHIFTS = (0.05, -0.05, 0.12, -0.12, 0.25, -0.25)


def segment_labels(system: System) -> list[str]:
    """Names of the N + 1 beam segments: ``laser->arm0``, ..., ``armN->target``."""
    ends = ["laser", *system.robot_names, "target"]
    return [f"{a}->{b}" for a, b in itertools.pairwise(ends)]


def occlusions(
    system: System, scene: SceneModel, solutions: list[Solution]
) -> dict[int, dict[str, object]]:
    """Evidence of every solved target whose beam is blocked, by solution index (the first
    blocked segment along the beam)."""
    idx = [k for k, s in enumerate(solutions) if s.ok and s.hits is not None]
    if scene.empty or not idx:
        return {}
    n_seg = system.n_robots + 1
    pts = [beam_vertices(system, solutions[k].hits, solutions[k].spot) for k in idx]  # type: ignore[arg-type]
    P = np.stack(pts)  # (M, N + 2, 3)
    blocked = scene.blocked_segments(
        P[:, :-1].reshape(-1, 3), P[:, 1:].reshape(-1, 3), START_MARGIN, END_MARGIN
    )
    labels = segment_labels(system)
    out: dict[int, dict[str, object]] = {}
    for hit in blocked:  # ordered by segment index: the first blocked segment comes first
        k = idx[hit.segment // n_seg]
        if k in out:
            continue
        q, j = solutions[k].q, hit.segment % n_seg
        start, end = P[hit.segment // n_seg, j], P[hit.segment // n_seg, j + 1]
        out[k] = {
            "segment": labels[j],
            "start": [float(x) for x in start],
            "end": [float(x) for x in end],
            "object": hit.object,
            "point": [float(x) for x in hit.point],
            "distance_m": hit.distance,
            "segment_length_m": hit.length,
            "q": None if q is None else [float(x) for x in q],
        }
    return out


def failed_occluded(sol: Solution, evidence: dict[str, object]) -> Solution:
    """``sol`` as a failed ``occluded`` target (no configuration, spot or hits)."""
    return failed_with(sol, Reason.OCCLUDED, evidence)


def check_points(
    ik: BeamIK,
    scene: SceneModel,
    targets: Targets,
    solutions: list[Solution],
    shifts: tuple[float, ...] = RETRY_SHIFTS,
) -> list[Solution]:
    """Point targets with blocked beams re-solved with other family members: the first
    mirror's hit slid along the incoming beam by each of ``shifts`` (m), then the member
    nearest home; the first clear one wins, else the target fails as ``occluded``."""
    system = ik.system
    blocked = occlusions(system, scene, solutions)
    if not blocked:
        return solutions
    out = list(solutions)
    for k, evidence in blocked.items():
        t0 = time.perf_counter()
        q_blocked = solutions[k].q
        assert q_blocked is not None  # only solved targets are checked
        seeds = [_slid(system, q_blocked, ds) for ds in shifts] + [system.home]
        for tried, seed in enumerate(seeds, start=1):
            sol = _member(ik, targets.points[k], targets.normal(k), seed)
            if sol is not None and not occlusions(system, scene, [sol]):
                dt = solutions[k].solve_time + time.perf_counter() - t0
                out[k] = dataclasses.replace(
                    sol, solve_time=dt, evidence={**sol.evidence, "occlusion_retry": tried}
                )
                break
        else:
            out[k] = failed_occluded(solutions[k], {**evidence, "retries": len(seeds)})
    return out


def _slid(system: System, q: Array, ds: float) -> Array:
    """Joints (stacked, rad) that move robot 0's mirror centre by ``ds`` m along the laser
    beam (one least-squares step through the finite-difference Jacobian of the centre)."""

    nq0 = system.robots[0].nq
    c0 = mirror_poses(system, q)[0][:3, 3]
    J = np.empty((3, nq0))
    for j in range(nq0):
        dq = np.zeros_like(q)
        dq[j] = 1e-6
        J[:, j] = (mirror_poses(system, q + dq)[0][:3, 3] - c0) / 1e-6
    v0 = system.world_T_laser[:3, 2] / np.linalg.norm(system.world_T_laser[:3, 2])
    out = q.copy()
    out[:nq0] += np.linalg.lstsq(J, ds * v0, rcond=None)[0]
    return out


def _member(ik: BeamIK, target: Array, normal: Array | None, seed: Array) -> Solution | None:
    """The closed-form member nearest ``seed`` if the IK accepts it (no multi-start: a retry
    looks for another member, not for a solution at any price); arms without a closed form
    go through the full :meth:`BeamIK.solve`."""
    if ik.closed_form is None:
        sol = ik.solve(target, normal, seed)
        return sol if sol.ok else None
    t0 = time.perf_counter()
    cf = ik.closed_form.search(target, normal, seed, ik.options.max_incidence)
    if cf.q is None:
        return None
    q = cf.q if ik.closed_form.exact else ik.newton.polish(cf.q, target, normal).q
    ev = trace_beam(ik.system, q, target, normal)
    if not ik.accept(ev, q):
        return None
    dt = time.perf_counter() - t0
    return Solution.solved(q, ev, dt, cf.members, "closed_form+retry", dict(cf.evidence))


def check_path(
    system: System, scene: SceneModel, solutions: list[Solution], path: PathResult
) -> tuple[list[Solution], PathResult]:
    """Path samples with blocked beams become ``occluded`` gaps: their solutions fail, the
    path result loses them (q NaN, ok False) and its feasible segments split around them."""
    blocked = occlusions(system, scene, solutions)
    gaps = {}
    for k, ev in blocked.items():
        detail = (f"beam {ev['segment']} blocked by {ev['object']} at "
                  f"{np.round(np.asarray(ev['point']), 4).tolist()} m")  # fmt: skip
        gaps[k] = SampleGap("occluded", ev, detail, np.asarray(ev["point"], dtype=float))
    return split_path(solutions, path, gaps)
