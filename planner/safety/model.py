"""The safety rules of one system, as the planner applies them to a configuration.

:class:`Safety` holds a system's scene objects, keep-out volumes and :class:`SafetySettings`
and builds the collision world (:class:`~planner.safety.geometry.SafetyWorld`) once, on first
use. For a stacked joint vector ``q`` (rad) and the beam polyline (world points, m: laser
exit, mirror hits, spot) it answers with the worst :class:`Violation` or None:

- arm-arm and arm-scene keep ``clearance`` (m), arm-self parts must not touch: one Pinocchio
  collision call with each pair's security margin set to its required distance (exact
  distances are computed only for the pairs it flags, as evidence);
- beam segments vs every arm part (own mirror skipped, own other parts must not be touched,
  every other part keeps ``clearance``) and vs every keep-out volume: the segments are
  collision objects of a second geometry model (:class:`~planner.safety.beam_pairs.BeamPairs`),
  all pairs in one Pinocchio call the same way;
- the beam returning into the laser aperture or the camera lens (within a cone).

A violation's evidence names the parts or volume, the distance and required distance (m)
and the world point where it happens. World frame, metres, radians throughout.
"""

from __future__ import annotations

import itertools
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import coal
import numpy as np
import pinocchio as pin

from planner.model.system import System
from planner.model.transforms import Array
from planner.safety.beam import ApertureHit, camera_lens, distance, laser_return
from planner.safety.beam_pairs import BeamPairs
from planner.safety.checks import CHECK_OF_PAIR, DEFAULT_CLEARANCE, Check, Clearance, pair_record
from planner.safety.geometry import PairKind, PartKind, SafetyWorld
from planner.safety.shapes import Volume, volumes_from_scene_items
from schemas.scenario import safety_margin

if TYPE_CHECKING:
    from planner.io.scenario import LoadedScenario


@dataclass(frozen=True)
class SafetySettings:
    """``clearance`` (m) arm-arm, arm-scene, beam-arm; a reflected segment within
    ``return_radius`` (m) of the laser exit travelling back within ``return_cone`` (rad) of
    its axis enters the aperture; the same radius within ``lens_cone`` (rad) of the camera's
    optical axis enters the lens. ``margin`` (m) inflates every keep-out volume and arm part
    for the beam checks: ``laser.beam_radius`` + 3 x the calibration's spot uncertainty
    (:func:`schemas.scenario.safety_margin`)."""

    clearance: float = DEFAULT_CLEARANCE
    return_cone: float = float(np.radians(10.0))
    return_radius: float = 0.01
    lens_cone: float = float(np.radians(45.0))
    margin: float = 0.0

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None, beam_radius: float = 0.0) -> SafetySettings:
        """From a scenario's ``safety`` mapping (``clearance``, ``return_cone_deg``,
        ``return_radius``, ``spot_uncertainty``) and ``laser.beam_radius`` (m); missing keys
        take the defaults."""
        d = d or {}
        base = cls()
        return cls(
            clearance=float(d.get("clearance", base.clearance)),
            return_cone=float(np.radians(d.get("return_cone_deg") or np.degrees(base.return_cone))),
            return_radius=float(d.get("return_radius", base.return_radius)),
            margin=safety_margin(beam_radius, float(d.get("spot_uncertainty") or 0.0)),
        )


@dataclass(frozen=True)
class Violation:
    """A broken safety rule: the check, its margin (m, distance - required, < 0), a one-line
    ``text`` and JSON-ready ``evidence`` (names, metres, world points)."""

    check: Check
    margin: float
    text: str
    evidence: dict[str, object] = field(default_factory=dict)

    @property
    def reason(self) -> str:
        """The plan's status reason: ``collision``, ``keep_out`` or ``occluded``."""
        return self.check.reason


def _round(x: Array) -> list[float]:
    return [round(float(v), 6) for v in x]


def segment_names(system: System) -> list[str]:
    """Names of the N + 1 beam segments: ``laser->arm0``, ..., ``armN->target``."""
    ends = ["laser", *system.robot_names, "target"]
    return [f"{a}->{b}" for a, b in itertools.pairwise(ends)]


def clearance_violation(c: Clearance, labels: Sequence[str] = ()) -> Violation:
    """A :class:`Clearance` record below its required distance as a :class:`Violation`."""
    a = labels[c.segment] if 0 <= c.segment < len(labels) else c.a
    a = f"beam {a}" if c.segment >= 0 else a
    evidence: dict[str, object] = {
        "check": c.check.value, "a": a, "b": c.b, "distance_m": float(c.distance),
        "required_m": float(c.required), "point": _round((c.p_a + c.p_b) / 2),
    }  # fmt: skip
    text = (f"{c.check.value}: {a} - {c.b} {c.distance * 1e3:.1f} mm apart (required "
            f"{c.required * 1e3:.1f} mm) at {evidence['point']} m (world)")  # fmt: skip
    return Violation(c.check, float(c.distance - c.required), text, evidence)


def aperture_violation(h: ApertureHit, labels: Sequence[str], radius: float) -> Violation:
    seg = labels[h.segment] if h.segment < len(labels) else str(h.segment)
    evidence: dict[str, object] = {
        "check": h.check.value, "a": f"beam {seg}", "b": h.what,
        "distance_m": float(h.distance), "required_m": float(radius),
        "angle_deg": float(np.degrees(h.angle)), "point": _round(h.point),
    }  # fmt: skip
    text = (f"{h.check.value}: beam {seg} enters the {h.what} ({h.distance * 1e3:.1f} mm from "
            f"its centre, {np.degrees(h.angle):.1f} deg off its axis) at {evidence['point']} m")  # fmt: skip
    return Violation(h.check, float(h.distance - radius), text, evidence)


class Safety:
    """The safety rules of ``system`` (see the module docstring); the collision world is
    built on first use. ``world_T_camera``: a fixed camera's pose (default: the system's
    fixed camera; a camera on a flange is posed by the configuration)."""

    def __init__(
        self,
        system: System,
        scene: Sequence[Volume] = (),
        keep_out: Sequence[Volume] = (),
        settings: SafetySettings | None = None,
    ) -> None:
        self.system = system
        self.scene = tuple(scene)
        self.keep_out = tuple(keep_out)
        self.settings = settings or SafetySettings()
        self.labels = segment_names(system)

    def twin(self) -> Safety:
        """The same rules with a collision world of their own (another thread's checks)."""
        return Safety(self.system, self.scene, self.keep_out, self.settings)

    @classmethod
    def from_scenario(cls, scn: LoadedScenario, system: System) -> Safety:
        """The rules of a loaded scenario: its ``scene`` objects, ``keep_out`` volumes and
        ``safety`` settings, for ``system`` (its resolved model)."""
        from planner.io.scenario import keep_out_objects, scene_objects

        m = scn.model
        settings = SafetySettings.from_dict(m.safety.model_dump(), m.system.laser.beam_radius)
        scene = volumes_from_scene_items(scene_objects(scn))
        return cls(system, scene, volumes_from_scene_items(keep_out_objects(scn)), settings)

    @cached_property
    def world(self) -> SafetyWorld:
        """The collision world, with each pair's security margin = its required distance."""
        world = SafetyWorld(self.system, self.scene, self.keep_out, bare=True)
        if world.unchecked:
            emit_warning(f"no collision geometry for robot(s) {', '.join(world.unchecked)}: "
                         "their links are not checked for collisions or beam clearance")  # fmt: skip
        for req, kind in zip(world.geom_data.collisionRequests, world.pair_kinds, strict=True):
            req.security_margin = self.required(kind)
        return world

    @cached_property
    def beam_pairs(self) -> BeamPairs:
        """The beam segments against the arm parts and keep-out volumes."""
        return BeamPairs(self.world, self.settings.clearance, self.settings.margin)

    def required(self, kind: PairKind) -> float:
        """Required distance (m) of a collision pair kind (arm-self parts must not touch)."""
        return 0.0 if kind is PairKind.ARM_SELF else self.settings.clearance

    # --- configuration checks ----------------------------------------------------------------
    def arms(self, q: Array) -> Violation | None:
        """Worst arm-arm, arm-self or arm-scene violation at stacked joints ``q`` (rad)."""
        world = self.world
        world.update(q)
        if not world.pair_kinds or not pin.computeCollisions(
            world.geom_model, world.geom_data, False
        ):
            return None
        worst: Clearance | None = None
        for i, res in enumerate(world.geom_data.collisionResults):
            if res.isCollision():
                kind = world.pair_kinds[i]
                pin.computeDistance(world.geom_model, world.geom_data, i)
                rec = pair_record(world, i, CHECK_OF_PAIR[kind], self.required(kind))
                if worst is None or rec.margin < worst.margin:
                    worst = rec
        if worst is None or worst.ok:  # coal flagged a pair its distance then clears
            return None
        return clearance_violation(worst)

    def _points(self, points: Array) -> Array:
        P = np.asarray(points, dtype=float)
        if P.shape != (self.system.n_robots + 2, 3) or not np.all(np.isfinite(P)):
            raise ValueError(f"beam polyline must be {self.system.n_robots + 2} finite world "
                             f"points (m), got {P.shape}")  # fmt: skip
        return P

    def _worst(self, records: list[Clearance], hits: list[Violation]) -> Violation | None:
        found = [clearance_violation(c, self.labels) for c in records] + hits
        return min(found, key=lambda v: v.margin, default=None)

    def geometry(self, points: Array) -> Violation | None:
        """Rules that depend on the beam polyline alone (``points``: (N + 2) x 3 world, m:
        laser exit, mirror hits, spot): keep-out volumes, the laser aperture, a fixed
        camera's lens. The worst violation."""
        P = self._points(points)
        records: list[Clearance] = []
        if self.keep_out:
            self.beam_pairs.place(P)
            records = self.beam_pairs.keep_out_violations()
        return self._worst(records, self._apertures(P, flange_camera=False))

    def configuration(self, q: Array, points: Array) -> Violation | None:
        """Rules that depend on the arms at stacked joints ``q`` (rad): arm-arm, arm-self,
        arm-scene, then the beam ``points`` against every arm part (and a flange camera)."""
        P = self._points(points)
        bad = self.arms(q)
        if bad is not None:
            return bad
        self.beam_pairs.place(P)
        records = [c for c in self.beam_pairs.violations() if c.check is Check.BEAM_ARM]
        return self._worst(records, self._apertures(P, fixed_camera=False))

    def beam(self, q: Array, points: Array, *, apertures: bool = True) -> Violation | None:
        """Every beam rule at stacked joints ``q``: arm parts, keep-out, laser, camera
        (``apertures=False``: only a flange camera's lens of the last two, the rest being
        checked by :meth:`apertures_batch`)."""
        P = self._points(points)
        self.world.update(q)
        self.beam_pairs.place(P)
        hits = self._apertures(P, fixed_camera=apertures)
        return self._worst(self.beam_pairs.violations(), hits)

    def apertures_batch(self, polylines: Array) -> tuple[int, Violation] | None:
        """The first of many beams (M x (N + 2) x 3, world, m) entering the laser aperture
        or a fixed camera's lens: (row, violation), or None."""
        s = self.settings
        P = np.asarray(polylines, dtype=float)
        devices = [(Check.LASER_RETURN, self.system.world_T_laser, s.return_cone, 1)]
        cam = self.system.camera
        if cam is not None and cam.robot is None:
            devices.append((Check.CAMERA_LENS, cam.world_T_camera, s.lens_cone, 0))
        first: tuple[int, Violation] | None = None
        for check, T, cone, k0 in devices:
            hit = aperture_rows(P, T, s.return_radius, cone, k0)
            if hit is not None and (first is None or hit[0] < first[0]):
                m, k = hit
                rows = laser_return if check is Check.LASER_RETURN else camera_lens
                h = rows(T, P[m], s.return_radius, cone)
                h = [x for x in h if x.segment == k] or h
                first = (m, aperture_violation(h[0], self.labels, s.return_radius))
        return first

    def config(self, q: Array, points: Array | None = None) -> Violation | None:
        """Every rule at stacked joints ``q`` (the beam ones only with a polyline)."""
        if points is None:
            return self.arms(q)
        return self.configuration(q, points) or self.geometry(points)

    def move_keep_out(self, world_T_objects: dict[str, Array]) -> None:
        """Place keep-out volumes (by name) at new poses (4 x 4, world, m): volumes attached
        to a moving object (``keep_out[].attached_to``) follow it. Unknown names are
        ignored; every later check sees the new poses."""
        world, pairs = self.world, self.beam_pairs
        for j, part in enumerate(pairs.parts):
            name = part.name.removeprefix("keep_out/")
            T = world_T_objects.get(name)
            if part.kind is not PartKind.KEEP_OUT or T is None:
                continue
            M = pin.SE3(np.asarray(T, dtype=float)[:3, :3], np.asarray(T, dtype=float)[:3, 3])
            world.geom_model.geometryObjects[part.index].placement = M
            world.geom_data.oMg[part.index] = M
            pairs.model.geometryObjects[j].placement = M
            pairs.data.oMg[j] = M
        world._placements = None  # the cached world poses are stale now

    def target(self, p: Array) -> Violation | None:
        """The target point ``p`` (world, m) inside a keep-out volume: the deepest one."""
        if not self.keep_out:
            return None
        x = np.asarray(p, dtype=float)
        world, point = self.world, coal.Sphere(0.0)
        worst: Violation | None = None
        for part in world.parts_of(PartKind.KEEP_OUT):
            T = coal.Transform3s(np.eye(3), x)
            d, _, _, nrm = distance(point, T, world.geometry(part.index),
                                    world.placement(part.index))  # fmt: skip
            if d < 0 and (worst is None or d < worst.margin):
                c = Clearance(Check.TARGET_KEEP_OUT, "target", part.name, d, 0.0, x, x, nrm,
                              -1, part.index)  # fmt: skip
                worst = clearance_violation(c)
        return worst

    # --- apertures ----------------------------------------------------------------------
    def world_T_camera(self) -> Array | None:
        """The camera pose at the last configuration (a flange camera moves with its arm)."""
        cam = self.system.camera
        if cam is None or cam.robot is None or cam.flange_T_camera is None:
            return None if cam is None else cam.world_T_camera
        k = self.system.robot_names.index(cam.robot)
        world, robot = self.world, self.system.robots[k]
        frame = robot.kinematics.model.frames[robot.kinematics.flange_id].placement.homogeneous
        return world.data.oMi[world.flange_joint[k]].homogeneous @ frame @ cam.flange_T_camera

    def _apertures(
        self, P: Array, *, fixed_camera: bool = True, flange_camera: bool = True
    ) -> list[Violation]:
        s = self.settings
        hits = []
        if fixed_camera:
            hits = laser_return(self.system.world_T_laser, P, s.return_radius, s.return_cone)
        on_flange = self.system.camera is not None and self.system.camera.robot is not None
        cam = self.world_T_camera() if (flange_camera if on_flange else fixed_camera) else None
        if cam is not None:
            hits += camera_lens(cam, P, s.return_radius, s.lens_cone)
        return [aperture_violation(h, self.labels, s.return_radius) for h in hits]


def aperture_rows(
    P: Array, world_T_device: Array, radius: float, cone: float, first: int
) -> tuple[int, int] | None:
    """First row m (and its segment k >= ``first``) of beams ``P`` (M x S x 3) passing
    within ``radius`` (m) of the device origin, travelling back along its +z within
    ``cone`` (rad); None if no row does."""
    hit = aperture_hits(P, world_T_device, radius, cone, first)
    if not hit.any():
        return None
    m, k = np.argwhere(hit)[0]
    return int(m), int(k) + first


def aperture_hits(P: Array, world_T_device: Array, radius: float, cone: float, first: int,
                  slack: float = 0.0) -> Array:  # fmt: skip
    """(M, S - 1 - first) which segments k >= ``first`` of beams ``P`` (M x S x 3) pass within
    ``radius`` (m) of the device origin, travelling back along its +z within ``cone``
    (rad); ``slack`` widens both bounds (m, and in the cosine) to err on the hit side."""
    c = world_T_device[:3, 3]
    axis = world_T_device[:3, 2] / np.linalg.norm(world_T_device[:3, 2])
    A, B = P[:, first:-1], P[:, first + 1 :]
    d = B - A
    L2 = np.maximum((d * d).sum(axis=2), 1e-300)
    cos = -(d @ axis) / np.sqrt(L2)
    s = np.clip(((c - A) * d).sum(axis=2) / L2, 0.0, 1.0)
    dist = np.linalg.norm(A + s[:, :, None] * d - c, axis=2)
    return np.asarray((cos >= np.cos(cone) - slack) & (dist <= radius + slack), dtype=bool)


def emit_warning(message: str) -> None:
    """One warning line on stderr."""

    print(f"warning: {message}", file=sys.stderr)
