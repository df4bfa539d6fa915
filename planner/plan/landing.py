"""Targets picked in the camera's view land on the scene surface that carries them.

A camera-frame target mapped to the world through the *calibrated* camera pose lies off the
scene's model surface by the camera's calibration error (the real camera saw it on the real
surface): a few mm behind the board, the board would hide it; in front, the spot would be
planned in the air. Such targets carry a ``surface_tolerance`` (m, :func:`surface_tolerance`).
After the IK, each solved target within that distance of a scene object (its *carrier*: the
object whose surface is nearest) has its solved beam's last segment cast against the scene
and on past the target. Where that ray first meets the carrier, at a point whose distance
from the target along the surface normal is within the tolerance (and along the beam within
:data:`MAX_SLANT` tolerances: a slanted beam meets the surface farther away), the target moves
there (:class:`Landing`: the object, the world point,
the signed offset along the beam) and is solved again at that point - the same beam, as the
point lies on it - under every rule the IK applies (a landing point inside a keep-out volume
fails as ``keep_out``, the beam keeps its clearances). The occlusion check then runs on the
landed targets unchanged: another object in front of the target, an arm, or the carrier's
surface farther than the tolerance from the target still block it. World frame, metres.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from planner.model.scene import START_MARGIN, SceneModel
from planner.model.system import Targets
from planner.model.transforms import Array
from schemas.defaults import SURFACE_TOLERANCE_M
from schemas.scenario import UNCERTAINTY_K

if TYPE_CHECKING:
    from planner.ik import BeamIK, Solution


#: the landing point lies at most this many tolerances from the target along the beam (a
#: beam 80 deg from the surface normal runs 5.8 times the target's depth below the surface)
MAX_SLANT = 6.0


def surface_tolerance(spot_uncertainty: float = 0.0) -> float:
    """How far (m) a camera-frame target may lie from the surface that carries it:
    :data:`~schemas.scenario.UNCERTAINTY_K` x the calibration's spot uncertainty (m), at
    least :data:`~schemas.defaults.SURFACE_TOLERANCE_M`."""
    return max(SURFACE_TOLERANCE_M, UNCERTAINTY_K * float(spot_uncertainty))


class Landing(NamedTuple):
    """Where a target's beam meets the surface that carries it: the scene object's ``name``, the world
    ``point`` (m), ``offset`` (m, signed along the beam: < 0 the surface lies before the
    requested target, > 0 beyond it) and the ``requested`` world point (m)."""

    name: str
    point: Array
    offset: float
    requested: Array

    def to_json(self) -> dict[str, object]:
        return {"object": self.name, "requested": [float(x) for x in self.requested],
                "offset_m": float(self.offset)}  # fmt: skip


def landings(
    scene: SceneModel, targets: Targets, solutions: list[Solution], tolerance: float
) -> dict[int, Landing]:
    """The :class:`Landing` of every solved target within ``tolerance`` (m) of its carrier
    whose beam meets the carrier first, within ``tolerance`` of the target along the
    surface normal (see the module docstring); targets whose beam does not carry them onto
    their carrier are left out."""
    idx = [k for k, s in enumerate(solutions) if s.ok and s.hits is not None]
    if scene.empty or not idx or tolerance <= 0:
        return {}
    near, carrier = scene.closest(targets.points[idx])
    idx = [k for k, d in zip(idx, near, strict=True) if d <= tolerance]
    carrier_of = dict(zip(idx, carrier[near <= tolerance], strict=True))
    if not idx:
        return {}
    starts = np.array([solutions[k].hits[-1] for k in idx])  # type: ignore[index]
    ends = targets.points[idx]
    length = np.linalg.norm(ends - starts, axis=1)
    v = (ends - starts) / length[:, None]
    hits = scene.cast(starts + START_MARGIN * v, v)
    out: dict[int, Landing] = {}
    for i, k in enumerate(idx):
        t = float(hits.t[i]) + START_MARGIN
        if hits.object[i] != carrier_of[k] or not np.isfinite(t):
            continue
        point = starts[i] + t * v[i]
        depth = abs(float(hits.normal[i] @ (point - ends[i])))  # off the surface, along its normal
        if depth <= tolerance and abs(t - length[i]) <= MAX_SLANT * tolerance:
            out[k] = Landing(scene.names[carrier_of[k]], point, t - length[i], ends[i].copy())
    return out


def land_on_surfaces(
    ik: BeamIK, scene: SceneModel | None, targets: Targets, solutions: list[Solution]
) -> tuple[Targets, list[Solution]]:
    """``targets`` with each landed one (:func:`landings`, ``targets.surface_tolerance``; on
    the live cloud, :func:`cloud_landings`, those the scene carries none of) moved onto its
    surface and solved again there from its first solution; the landed solutions carry
    their :class:`Landing` as ``evidence["surface"]``."""
    tol = targets.surface_tolerance
    found = {} if scene is None else landings(scene, targets, solutions, tol)
    if targets.cloud is not None:
        found |= cloud_landings(targets.cloud, targets, solutions, tol, set(found))
    if not found:
        return targets, solutions
    points = targets.points.copy()
    out = list(solutions)
    for k, land in found.items():
        points[k] = land.point
        sol = ik.solve(land.point, targets.normal(k), solutions[k].q)
        solve_time = solutions[k].solve_time + sol.solve_time
        evidence = {**sol.evidence, "surface": land.to_json()}
        out[k] = dataclasses.replace(sol, solve_time=solve_time, evidence=evidence)
    return dataclasses.replace(targets, points=points), out


def land_path(
    scene: SceneModel, targets: Targets, solutions: list[Solution]
) -> tuple[Targets, dict[int, Landing]] | None:
    """A camera-frame path's samples moved onto the surface their beam lands on: each landed
    sample (:func:`landings`, ``targets.surface_tolerance``) to its landing point, every
    other one (no beam, or not onto its carrier) by the landing displacement interpolated
    along the path between the landed samples around it (the camera's calibration error
    moves a path as a whole; beyond the first or last landed sample, theirs). The moved
    targets and the landings by sample, or None when no sample landed."""
    found = landings(scene, targets, solutions, targets.surface_tolerance)
    if not found:
        return None
    idx = np.array(sorted(found))
    shift = np.array([found[k].point - targets.points[k] for k in idx])
    ks = np.arange(len(targets))
    d = np.column_stack([np.interp(ks, idx, shift[:, i]) for i in range(3)])
    return dataclasses.replace(targets, points=targets.points + d), found


#: m: cloud points this close to a target's beam (its last segment's line) sample the surface
#: it meets there
CLOUD_RADIUS = 0.004
#: fewest cloud points that make a surface
CLOUD_MIN_POINTS = 12
#: m: largest RMS distance of those points from their plane (a surface, not a corner or an edge)
CLOUD_MAX_RMS = 0.001
#: the name a landing on the live cloud reports as its carrier
CLOUD = "camera cloud"


def cloud_landings(
    cloud: Array, targets: Targets, solutions: list[Solution], tolerance: float,
    skip: set[int] | frozenset[int] = frozenset(),
) -> dict[int, Landing]:  # fmt: skip
    """Landings on the camera's live cloud (``cloud``: N x 3 world points, m, through the
    calibrated camera pose) of the solved targets not in ``skip``: the cloud points within
    :data:`CLOUD_RADIUS` of the target's beam line and within :data:`MAX_SLANT` x
    ``tolerance`` of the target along it, at least :data:`CLOUD_MIN_POINTS`, lying on a
    plane (RMS under :data:`CLOUD_MAX_RMS`; SVD fit) are the surface there; the beam meets
    that plane at the landing point, taken when it lies within ``tolerance`` of the target
    along the plane's normal and within :data:`MAX_SLANT` x ``tolerance`` along the beam (a
    grazing beam meets a plane far beyond the sampled patch). A pick on the cloud lands where
    the many points around it put the surface, not at its own pixel's noisy depth."""
    out: dict[int, Landing] = {}
    cloud = np.asarray(cloud, dtype=float).reshape(-1, 3)
    if len(cloud) < CLOUD_MIN_POINTS or tolerance <= 0:
        return out
    for k, sol in enumerate(solutions):
        if k in skip or not sol.ok or sol.hits is None:
            continue
        start, end = sol.hits[-1], targets.points[k]
        v = (end - start) / np.linalg.norm(end - start)
        rel = cloud - end
        along = rel @ v
        near = (np.abs(along) <= MAX_SLANT * tolerance) & (
            np.linalg.norm(rel - along[:, None] * v, axis=1) <= CLOUD_RADIUS
        )
        pts = cloud[near]
        if len(pts) < CLOUD_MIN_POINTS:
            continue
        centre = pts.mean(axis=0)
        _, sv, vt = np.linalg.svd(pts - centre, full_matrices=False)
        normal = vt[2]
        if sv[2] / np.sqrt(len(pts)) > CLOUD_MAX_RMS or abs(normal @ v) < 1e-3:
            continue
        t = float(normal @ (centre - end) / (normal @ v))  # from the target along the beam
        point = end + t * v
        if abs(float(normal @ (point - end))) <= tolerance and abs(t) <= MAX_SLANT * tolerance:
            out[k] = Landing(CLOUD, point, t, end.copy())
    return out
