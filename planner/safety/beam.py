"""Beam safety: the beam polyline against the arms and keep-out volumes, targets inside
keep-out, and the beam returning into the laser aperture or the camera lens.

The beam is a polyline of world points (m): laser exit, the hit on mirror 1, ..., the hit
on mirror N, the spot (or any end point). Segment k runs from point k to point k + 1; point
k (1 <= k <= N) lies on robot k-1's mirror. A segment is a coal capsule of radius 0, so
every distance is exact to coal's GJK tolerance (1e-12 m here).

Rules at the mirrors: a segment that starts or ends on robot i's mirror skips that mirror
plate (the beam touches it by construction, and a valid reflection leaves into the front
half-space, away from the plate) and needs only to miss robot i's other parts (its mount and
wrist sit within a few mm of the mirror by construction); every other part keeps the
clearance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import coal
import numpy as np

from planner.model.status import Reason
from planner.model.transforms import Array
from planner.safety.checks import DEFAULT_CLEARANCE, Check, Clearance
from planner.safety.geometry import PartKind, SafetyWorld, capsule_placement

_REQUEST = coal.DistanceRequest()
_REQUEST.gjk_tolerance = 1e-12


@dataclass(frozen=True)
class ApertureHit:
    """Beam segment ``segment`` passes ``distance`` m from the centre of ``what`` (laser
    aperture or camera lens) at world ``point``, travelling back along its axis within
    ``angle`` rad: it would enter it."""

    check: Check
    what: str
    segment: int
    distance: float
    angle: float
    point: Array

    @property
    def reason(self) -> Reason:
        return self.check.reason

    def __str__(self) -> str:
        return (
            f"{self.check.value}: beam segment {self.segment} enters the {self.what}"
            f" ({self.distance * 1000:.1f} mm from its centre, {np.degrees(self.angle):.1f} deg"
            f" off its axis) at {np.round(self.point, 4).tolist()} m (world)"
        )


def _transform(T: Array) -> coal.Transform3s:
    return coal.Transform3s(np.asarray(T[:3, :3]), np.asarray(T[:3, 3]))


def distance(
    geom_a: coal.CollisionGeometry,
    T_a: coal.Transform3s,
    geom_b: coal.CollisionGeometry,
    T_b: coal.Transform3s,
) -> tuple[float, Array, Array, Array]:
    """coal signed distance (m), witness points a and b, normal a -> b (world)."""
    res = coal.DistanceResult()
    d = coal.distance(geom_a, T_a, geom_b, T_b, _REQUEST, res)
    return (
        float(d),
        np.array(res.getNearestPoint1()),
        np.array(res.getNearestPoint2()),
        np.array(res.normal),
    )


def segment_shape(p0: Array, p1: Array) -> tuple[coal.Capsule, coal.Transform3s]:
    """The segment p0 -> p1 (world, m) as a coal capsule of radius 0 and its pose."""
    T, length = capsule_placement(p0, p1)
    return coal.Capsule(0.0, length), _transform(T)


def _as_points(points: Array) -> Array:
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2 or not np.all(np.isfinite(P)):
        raise ValueError(f"beam polyline must be >= 2 finite world points (m), got {P.shape}")
    return P


def beam_arm(
    world: SafetyWorld,
    q: Array,
    points: Array,
    clearance: float = DEFAULT_CLEARANCE,
    margin: float = 0.0,
) -> list[Clearance]:
    """Every beam segment against every part of every robot at stacked joints ``q`` (rad);
    every part inflated by ``margin`` (m)."""
    P = _as_points(points)
    world.update(q)
    n = world.system.n_robots
    out = []
    for k in range(len(P) - 1):
        ends = {r for r in (k - 1, k) if 0 <= r < n}  # robots whose mirror the segment touches
        seg, T_seg = segment_shape(P[k], P[k + 1])
        for part in world.parts:
            if not part.on_robot:
                continue
            own = part.robot in ends
            if own and part.kind is PartKind.MIRROR:
                continue
            d, pa, pb, nrm = distance(
                seg, T_seg, world.geometry(part.index), world.placement(part.index)
            )
            out.append(
                Clearance(
                    Check.BEAM_ARM,
                    f"beam[{k}]",
                    part.name,
                    d,
                    (0.0 if own else clearance) + margin,
                    pa,
                    pb,
                    nrm,
                    -1,
                    part.index,
                    k,
                )
            )
    return out


def beam_keep_out(world: SafetyWorld, points: Array, margin: float = 0.0) -> list[Clearance]:
    """Every beam segment against every keep-out volume (required distance ``margin``, m)."""
    P = _as_points(points)
    out = []
    for part in world.parts_of(PartKind.KEEP_OUT):
        geom, T = world.geometry(part.index), world.placement(part.index)
        for k in range(len(P) - 1):
            seg, T_seg = segment_shape(P[k], P[k + 1])
            d, pa, pb, nrm = distance(seg, T_seg, geom, T)
            out.append(
                Clearance(
                    Check.BEAM_KEEP_OUT,
                    f"beam[{k}]",
                    part.name,
                    d,
                    margin,
                    pa,
                    pb,
                    nrm,
                    -1,
                    part.index,
                    k,
                )
            )
    return out


def target_keep_out(world: SafetyWorld, targets: Array) -> list[Clearance]:
    """Each target point (K x 3, world, m) against each keep-out volume: a target inside
    one (signed distance < 0) is a violation; ``a`` names the target by its row."""
    X = np.asarray(targets, dtype=float).reshape(-1, 3)
    point = coal.Sphere(0.0)
    out = []
    for part in world.parts_of(PartKind.KEEP_OUT):
        geom, T = world.geometry(part.index), world.placement(part.index)
        for k, x in enumerate(X):
            d, pa, pb, nrm = distance(point, coal.Transform3s(np.eye(3), x), geom, T)
            out.append(
                Clearance(
                    Check.TARGET_KEEP_OUT,
                    f"target[{k}]",
                    part.name,
                    d,
                    0.0,
                    pa,
                    pb,
                    nrm,
                    -1,
                    part.index,
                )
            )
    return out


def _into(
    check: Check, what: str, P: Array, world_T_device: Array, radius: float, cone: float, first: int
) -> list[ApertureHit]:
    """Segments ``first..`` of ``P`` passing within ``radius`` of the device centre while
    travelling back along its axis within ``cone`` (plain floats: a polyline has a few
    segments and this runs per configuration)."""
    cx, cy, cz = (float(v) for v in world_T_device[:3, 3])
    ax, ay, az = (float(v) for v in world_T_device[:3, 2])
    na = math.sqrt(ax * ax + ay * ay + az * az)
    cos_cone = math.cos(cone)
    pts = P.tolist()
    out = []
    for k in range(first, len(pts) - 1):
        (px, py, pz), (qx, qy, qz) = pts[k], pts[k + 1]
        dx, dy, dz = qx - px, qy - py, qz - pz
        L2 = dx * dx + dy * dy + dz * dz
        if L2 == 0.0:
            continue
        cos = -(dx * ax + dy * ay + dz * az) / (math.sqrt(L2) * na)
        if cos < cos_cone:
            continue
        s = min(max(((cx - px) * dx + (cy - py) * dy + (cz - pz) * dz) / L2, 0.0), 1.0)
        x = (px + s * dx, py + s * dy, pz + s * dz)
        dist = math.dist((cx, cy, cz), x)
        if dist <= radius:
            angle = math.acos(min(max(cos, -1.0), 1.0))
            out.append(ApertureHit(check, what, k, dist, angle, np.array(x)))
    return out


def laser_return(
    world_T_laser: Array, points: Array, radius: float = 0.01, cone: float = np.radians(10.0)
) -> list[ApertureHit]:
    """Reflected segments that pass within ``radius`` (m) of the laser exit travelling back
    within ``cone`` (rad) of the laser axis (+z of ``world_T_laser``, reversed)."""
    return _into(
        Check.LASER_RETURN, "laser aperture", _as_points(points), world_T_laser, radius, cone, 1
    )


def camera_lens(
    world_T_camera: Array, points: Array, radius: float = 0.01, cone: float = np.radians(45.0)
) -> list[ApertureHit]:
    """Segments that pass within ``radius`` (m) of the camera centre travelling into it within
    ``cone`` (rad) of its optical axis (+z of ``world_T_camera``, OpenCV frame)."""
    return _into(
        Check.CAMERA_LENS, "camera lens", _as_points(points), world_T_camera, radius, cone, 0
    )


def trace(world: SafetyWorld, q: Array) -> tuple[Array, Array]:
    """The beam at stacked joints ``q`` through each mirror's surface (the seam of
    :mod:`planner.model.mirror`, as the beam model traces it): the points
    laser exit, hit on mirror 1, ..., hit on mirror N ((N + 1) x 3, world, m; a miss gives
    NaN) and the unit direction leaving the last mirror."""
    world.update(q)
    sys_ = world.system
    p, v = sys_.world_T_laser[:3, 3], sys_.world_T_laser[:3, 2]
    v = v / np.linalg.norm(v)
    pts = [p]
    for k, robot in enumerate(sys_.robots):
        wTm = world.data.oMi[world.flange_joint[k]].homogeneous @ world.joint_T_mirror[k]
        t, hit, _ = robot.mirror.intersect(wTm, p, v)
        v = robot.mirror.reflect(wTm, v, hit)
        p = hit if np.isfinite(t) else np.full(3, np.nan)
        pts.append(p)
    return np.array(pts), v


def beam_points(world: SafetyWorld, q: Array, end: Array | Sequence[float]) -> Array:
    """The polyline laser -> mirror hits -> ``end`` at stacked joints ``q``, the mirror hits
    through each mirror's surface (world, m); a miss gives NaN rows."""
    pts, _ = trace(world, q)
    return np.vstack([pts, np.asarray(end, dtype=float)])
