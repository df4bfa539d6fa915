"""``beamrelay check``: the safety rules re-checked with the checker's own numpy geometry.

For every solved target and every trajectory sample (at the scenario ``rate``): two arms
and an arm and a scene object keep ``safety.clearance`` (m), a robot's non-adjacent links
(and its mirror and mount against its links) do not touch; while the laser may be on (the
``trajectory.laser_on`` intervals, else the ``path`` and ``dwell`` segments) and at every
solved target, the beam (laser exit -> mirror hits -> spot) keeps the clearance from every
arm part but the mirror it reflects off (that robot's other parts must only not be
touched), never enters a keep-out volume, and does not travel back into the laser aperture
or the camera lens (within ``safety.return_radius`` m and ``return_cone_deg`` of their
axes; the lens within :data:`LENS_CONE_DEG`). A solved target inside a keep-out volume is a
violation. Keep-out volumes and arm parts are inflated for the beam by the margin
``laser.beam_radius`` + :data:`UNCERTAINTY_K` x ``safety.spot_uncertainty`` (the included
calibration's, echoed in the plan; docs/conventions.md section 4), computed here from the echo (a mesh
volume's planes move out by it: at its edges that is a little more than the margin).
Only UR5e arms are modelled (a URDF arm is reported as not checked); a scene
mesh is not re-checked (warning); a cylinder is checked against bounds of its true
distance, and only a sure violation counts. World frame, metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.model.status import Reason
from planner.model.transforms import Array
from planner.verify import arms
from planner.verify import batch_distances as bd
from planner.verify.context import CheckResult, PlanContext, spots, times
from planner.verify.findings import Finding
from planner.verify.numpy_beam import BeamRays, trace_rays
from planner.verify.safety_setup import Hit, Setup
from planner.verify.safety_shapes import (
    Shape,
    cylinder_inner,
    distance,
    near_distances,
)

#: deg: the camera lens cone (the planner's ``SafetySettings.lens_cone``)
LENS_CONE_DEG = 45.0
#: m: numerical allowance between this geometry and the planner's (coal, GJK 1e-12 m)
SLACK = 1e-6
#: configurations measured at once
CHUNK = 4096
LASER_KINDS = ("path", "dwell")
#: m: a beam passing this close to a target ends there; else it runs on for BEYOND m
ON_TARGET, BEYOND = 0.01, 2.0


def _self_pairs(parts: list[Shape]) -> list[tuple[Shape, Shape]]:
    out = []
    for i, a in enumerate(parts):
        for b in parts[i + 1 :]:
            la, lb = a.link, b.link
            if (a.name, b.name) in arms.SELF_EXCLUDED or (la == 7 and lb == 7):
                continue
            if (7 in (la, lb) and min(la, lb) < 6) or (7 not in (la, lb) and abs(la - lb) >= 2):
                out.append((a, b))
    return out


def _collect(hits: list[Hit], d: Array, bound: float, check: str, what: str, reason: str) -> None:
    """The rows where ``d`` < ``bound`` - SLACK become hits; with ``bound`` 0 (must not
    touch) also where d is 0 (box distances are 0 wherever the shapes meet)."""
    bad = (d < bound - SLACK) | ((bound <= 0.0) & (d <= 0.0))
    for m in np.flatnonzero(bad):
        hits.append(Hit(int(m), check, what, float(d[m]), bound, reason))


def arm_hits(setup: Setup, Q: dict[str, Array], shapes: list[list[Shape]] | None = None
             ) -> tuple[list[Hit], list[str]]:  # fmt: skip
    """Arm-arm, arm-self and arm-scene violations at joint rows Q (``shapes``: the arms'
    shapes there, :meth:`Setup.shapes`, when already placed); and warnings."""
    hits: list[Hit] = []
    warnings: list[str] = []
    c = setup.clearance
    per_robot = setup.shapes(Q) if shapes is None else shapes
    for i, parts in enumerate(per_robot):
        name = setup.robots[i]["name"]
        for a, b in _self_pairs(parts):
            d = near_distances(a, b, SLACK)
            _collect(hits, d, 0.0, "arm_self", f"{name}/{a.name} - {name}/{b.name}", "collision")
        for j in range(i + 1, len(per_robot)):
            other = setup.robots[j]["name"]
            for a in parts:
                for b in per_robot[j]:
                    d = near_distances(a, b, c)
                    _collect(hits, d, c, "arm_arm", f"{name}/{a.name} - {other}/{b.name}",
                             "collision")  # fmt: skip
        for obj in setup.scene:
            if obj.kind == "hull":
                continue
            for a in (p for p in parts if p.link > 0):  # the base stands on the scene
                d = near_distances(a, obj, c)
                what = f"{name}/{a.name} - scene/{obj.name}"
                if obj.kind == "cylinder":
                    lower = d
                    d = np.where(np.isfinite(d), distance(a, cylinder_inner(obj)), np.inf)
                    if np.any((lower < c - SLACK) & (d >= c - SLACK)):
                        warnings.append(f"{what}: within {c * 1e3:.0f} mm of the cylinder's "
                                        "bounding box (not decided by the numpy geometry)")  # fmt: skip
                _collect(hits, d, c, "arm_scene", what, "collision")
    for obj in setup.scene:
        if obj.kind == "hull":
            warnings.append(f"scene/{obj.name}: a mesh; arms are not re-checked against it")
    return hits, warnings


def target_hits(setup: Setup, P: Array) -> list[Hit]:
    """Targets (M, 3) inside a keep-out volume (deeper than SLACK)."""
    hits: list[Hit] = []
    for v in setup.keep:
        if v.kind == "sphere":
            depth = v.r - np.linalg.norm(P - v.A, axis=1)
        elif v.kind == "box":
            u = np.abs(np.einsum("ji,mj->mi", v.T[0, :3, :3], P - v.T[0, :3, 3]))
            depth = (v.ext / 2 - u).min(axis=1)
        else:
            depth = -(P @ v.planes[:, :3].T + v.planes[:, 3]).max(axis=1)
        for m in np.flatnonzero(depth > SLACK):
            hits.append(Hit(int(m), "target_keep_out", f"target inside keep_out/{v.name}",
                            -float(depth[m]), 0.0, "keep_out"))  # fmt: skip
    return hits


def _aperture(P: Array, T: Array, radius: float, cone: float, first: int) -> tuple[Array, Array]:
    """Per row (beams P: M x S x 3): whether a segment >= ``first`` passes within ``radius``
    of the device origin travelling back along its +z within ``cone``, and that distance."""
    c = T[..., :3, 3]
    axis = T[..., :3, 2] / np.linalg.norm(T[..., :3, 2], axis=-1, keepdims=True)
    A, B = P[:, first:-1], P[:, first + 1 :]
    if A.shape[1] == 0:
        return np.zeros(len(P), dtype=bool), np.full(len(P), np.inf)
    d = B - A
    L = np.maximum(np.linalg.norm(d, axis=2), 1e-300)
    c_ = c[:, None, :] if c.ndim == 2 else c
    ax = axis[:, None, :] if axis.ndim == 2 else axis
    back = -(d * ax).sum(axis=2) / L >= np.cos(cone)
    dist = np.where(back, bd.point_segment(c_, A, B), np.inf)
    return np.asarray((dist <= radius).any(axis=1)), np.asarray(dist.min(axis=1))


def beam_hits(setup: Setup, Q: dict[str, Array], P: Array,
              shapes: list[list[Shape]] | None = None) -> list[Hit]:  # fmt: skip
    """Beam violations of polylines P (M x (N + 2) x 3: laser exit, hits, spot) at joint
    rows Q (``shapes``: the arms' shapes there, when already placed): arm parts, keep-out
    volumes, laser aperture, camera lens."""
    hits: list[Hit] = []
    c = setup.clearance
    per_robot = setup.shapes(Q) if shapes is None else shapes
    for k in range(P.shape[1] - 1):
        seg = Shape(f"beam[{k}]", "capsule", A=P[:, k], B=P[:, k + 1])
        label = _segment_label(setup, k)
        for i, parts in enumerate(per_robot):
            own = i in (k - 1, k)
            for part in parts:
                if own and part.name == "mirror":
                    continue
                bound = (0.0 if own else c) + setup.margin
                d = near_distances(seg, part, bound + SLACK)
                what = f"beam {label} - {setup.robots[i]['name']}/{part.name}"
                _collect(hits, d, bound, "beam_arm", what, "occluded")
        e = setup.margin
        for v in setup.keep:
            inside: Any
            depth: Any = np.zeros(len(P))  # distance (m) from the volume, where measured
            if v.kind == "sphere":
                depth = bd.point_segment(v.A, seg.A, seg.B) - v.r
                inside = depth < e - SLACK
            elif v.kind == "box" and e > SLACK:
                depth = bd.segment_box(seg.A, seg.B, v.T, v.ext)
                inside = depth < e - SLACK
            elif v.kind == "box":
                inside = bd.segment_box(seg.A, seg.B, v.T, np.maximum(v.ext - 2 * SLACK, 0)) == 0
            else:
                inside = bd.segment_hull_meets(seg.A, seg.B, v.planes, SLACK - e)
            what = f"beam {label} enters keep_out/{v.name}"
            if e > 0:
                what += f" inflated by {e * 1e3:.2f} mm"
            for m in np.flatnonzero(inside):
                hits.append(Hit(int(m), "beam_keep_out", what, float(np.broadcast_to(
                    depth, (len(P),))[m]), e, "keep_out"))  # fmt: skip
    back, dist = _aperture(P, setup.laser, setup.radius, setup.cone, 1)
    for m in np.flatnonzero(back):
        hits.append(Hit(int(m), "laser_return", "beam returns into the laser aperture",
                        float(dist[m]), setup.radius, "keep_out"))  # fmt: skip
    cam = _camera_poses(setup, Q, len(P))
    if cam is not None:
        lens, dist = _aperture(P, cam, setup.radius, np.radians(LENS_CONE_DEG), 0)
        for m in np.flatnonzero(lens):
            hits.append(Hit(int(m), "camera_lens", "beam enters the camera lens",
                            float(dist[m]), setup.radius, "keep_out"))  # fmt: skip
    return hits


def _segment_label(setup: Setup, k: int) -> str:
    ends = ["laser", *(r["name"] for r in setup.robots), "target"]
    return f"{ends[k]}->{ends[k + 1]}"


def _camera_poses(setup: Setup, Q: dict[str, Array], M: int) -> Array | None:
    cam = setup.camera
    if cam is None:
        return None
    if cam["robot"] is None:
        return cam["T"]
    r = next(r for r in setup.robots if r["name"] == cam["robot"])
    return r["base"] @ Setup.flange(r, Q) @ cam["T"]


def polylines(setup: Setup, Q: dict[str, Array], ends: Array | None, targets: Array,
              rays: BeamRays | None = None) -> Array:  # fmt: skip
    """Beams at joint rows Q (``rays``: their trace, when already traced): laser exit,
    mirror hits, then ``ends`` (M x 3) or, without them, the point of the last ray nearest
    the closest target ahead when it passes within :data:`ON_TARGET` of it, else
    :data:`BEYOND` m out (a beam off the targets must stay clear that far)."""
    if rays is None:
        rays = trace_rays(setup.laser, setup.mirrors(Q))
    if ends is None:
        ends = rays.p + BEYOND * rays.v
        for a in range(0, len(rays.p), 256):
            p, v = rays.p[a : a + 256, None, :], rays.v[a : a + 256, None, :]
            w = targets[None, :, :] - p
            s = (w * v).sum(axis=2)
            perp = np.where(s > 0, np.linalg.norm(w - s[:, :, None] * v, axis=2), np.inf)
            rows = np.arange(len(perp))
            best = np.argmin(perp, axis=1)
            on = perp[rows, best] <= ON_TARGET
            spot = p[:, 0] + s[rows, best][:, None] * v[:, 0]
            ends[a : a + 256] = np.where(on[:, None], spot, ends[a : a + 256])
    p0 = np.broadcast_to(setup.laser[:3, 3], rays.p.shape)
    return np.stack([p0, *rays.hits, ends], axis=1)


def _worst_per_row(hits: list[Hit]) -> dict[int, Hit]:
    out: dict[int, Hit] = {}
    for h in hits:
        if h.row not in out or h.value - h.bound < out[h.row].value - out[h.row].bound:
            out[h.row] = h
    return out


def _text(h: Hit) -> str:
    if h.check in ("beam_keep_out", "target_keep_out"):
        return f"{h.check}: {h.what}"
    return f"{h.check}: {h.what} {h.value * 1e3:.2f} mm (required {h.bound * 1e3:.1f} mm)"


def check_safety(ctx: PlanContext) -> CheckResult:
    """Every solved target: arms clear of each other and of the scene, the beam clear of the
    arms and the keep-out volumes and not back into the laser or camera, the target outside
    every keep-out volume."""
    res = CheckResult("safety", len(ctx.solved))
    setup = ctx.safety_setup
    res.warnings += [
        f"{n}: a URDF arm, or a model without checker shapes; its links are not re-checked"
        for n in setup.unchecked
    ]
    if not ctx.solved:
        return res
    spot, _, _ = spots(ctx.rays.p, ctx.rays.v, ctx.P, ctx.N)
    shapes = setup.shapes(ctx.Q)
    found, warnings = arm_hits(setup, ctx.Q, shapes)
    found += beam_hits(setup, ctx.Q, polylines(setup, ctx.Q, spot, ctx.P, ctx.rays), shapes)
    found += target_hits(setup, ctx.P)
    res.warnings += sorted(set(warnings))
    for m, h in sorted(_worst_per_row(found).items()):
        res.findings.append(Finding("safety", int(ctx.ids[m]), _text(h), h.value, h.bound,
                                    Reason(h.reason)))  # fmt: skip
    res.figures = {"keep_out_volumes": float(len(setup.keep)), "clearance_m": setup.clearance,
                   "margin_m": setup.margin}  # fmt: skip
    return res


def laser_mask(traj: dict[str, Any], t: Array) -> Array:
    """Samples at which the laser may be on: ``laser_on`` intervals, else path and dwell."""
    spans = traj.get("laser_on")
    if spans is None:
        spans = [(s["t0"], s["t1"]) for s in traj.get("segments") or [] if s["kind"] in LASER_KINDS]
    mask = np.zeros(len(t), dtype=bool)
    for a, b in spans:
        mask |= (t >= float(a) - 1e-9) & (t <= float(b) + 1e-9)
    return mask


def check_trajectory_safety(ctx: PlanContext) -> CheckResult:
    """Every trajectory sample: arms clear (as for the targets); while the laser may be on,
    the beam clear as well (its spot at the nearest target)."""
    traj = ctx.plan.get("trajectory") or {}
    t = times(ctx.plan)
    res = CheckResult("trajectory safety", len(t))
    if not len(t):
        return res
    setup = ctx.safety_setup
    Q = {r["name"]: np.asarray(traj["q"][r["name"]], dtype=float) for r in setup.robots}
    on = laser_mask(traj, t)
    targets = np.array([tg["p"] for tg in ctx.plan["targets"]], dtype=float).reshape(-1, 3)
    first: dict[str, tuple[float, Hit, int]] = {}
    for a in range(0, len(t), CHUNK):
        rows = np.arange(a, min(a + CHUNK, len(t)))
        Qc = {k: v[rows] for k, v in Q.items()}
        shapes = setup.shapes(Qc)
        hits, _ = arm_hits(setup, Qc, shapes)
        lit = np.flatnonzero(on[rows])
        if len(lit):
            Ql = {k: v[lit] for k, v in Qc.items()}
            lit_shapes = [[s.rows(lit) for s in parts] for parts in shapes]
            beam = beam_hits(setup, Ql, polylines(setup, Ql, None, targets), lit_shapes)
            hits += [h._replace(row=int(lit[h.row])) for h in beam]
        for h in hits:
            tt, _, n = first.get(h.check, (np.inf, h, 0))
            t_h = float(t[rows[h.row]])
            first[h.check] = (t_h, h, n + 1) if t_h < tt else (tt, first[h.check][1], n + 1)
    for tt, h, n in first.values():
        res.findings.append(Finding("trajectory safety", None, f"{_text(h)} at t = {tt:.3f} s "
                                    f"({n} violation(s))", h.value, h.bound, Reason(h.reason)))  # fmt: skip
    res.figures = {"laser_on_samples": float(on.sum())}
    return res
