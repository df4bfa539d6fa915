"""The beam's segments as collision objects, checked against the arms and keep-out volumes in
one Pinocchio call.

:class:`BeamPairs` is a second Pinocchio ``GeometryModel`` over a
:class:`~planner.safety.geometry.SafetyWorld`'s kinematic model: the robots' parts and the
keep-out volumes (the same coal shapes) and the N + 1 beam segments (coal capsules of radius
0 on the universe joint, re-placed and re-sized for every beam). Pairs: every segment
against every robot part, except a segment that starts or ends on a robot's mirror against
that mirror plate (the beam touches it by construction); such a segment must only not touch
that robot's other parts, every other part keeps the clearance; every segment against every
keep-out volume must not enter it; every required distance grows by the safety margin
(beam radius + 3 x the calibration's spot uncertainty). Each pair's security margin is its required distance, so
``computeCollisions`` answers "any violation?" in C++; distances (the evidence) are computed
only for the pairs it flags. World frame, metres.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from planner.model.transforms import Array
from planner.safety.checks import Check, Clearance
from planner.safety.geometry import PartKind, SafetyWorld, capsule_placement


def _se3(T: Array) -> pin.SE3:
    return pin.SE3(T[:3, :3].copy(), T[:3, 3].copy())


class BeamPairs:
    """Beam segments vs arm parts and keep-out volumes of ``world`` (module docstring);
    ``clearance`` (m) is the distance every part keeps from a segment that does not touch
    its own robot's mirror; ``margin`` (m) inflates every part and keep-out volume (beam
    radius + 3 x the calibration's spot uncertainty): a segment keeps ``margin`` from a
    keep-out volume and from its own robot's parts, ``clearance + margin`` from the others."""

    def __init__(self, world: SafetyWorld, clearance: float, margin: float = 0.0) -> None:
        import coal

        self.world = world
        n = world.system.n_robots
        gm = pin.GeometryModel()
        src = [p for p in world.parts if p.on_robot or p.kind is PartKind.KEEP_OUT]
        self.parts = src
        for p in src:
            o = world.geom_model.geometryObjects[p.index]
            gm.addGeometryObject(pin.GeometryObject(p.name, o.parentJoint, o.placement, o.geometry))
        self.segments = [
            gm.addGeometryObject(
                pin.GeometryObject(f"beam[{k}]", 0, pin.SE3.Identity(), coal.Capsule(0.0, 1.0))
            )
            for k in range(n + 1)
        ]
        self.pair_info: list[tuple[Check, int, int, float]] = []  # check, segment, part row, req
        for k, seg in enumerate(self.segments):
            for j, p in enumerate(src):
                if p.kind is PartKind.KEEP_OUT:
                    self._pair(gm, Check.BEAM_KEEP_OUT, k, seg, j, margin)
                    continue
                own = p.robot in (k - 1, k)
                if own and p.kind is PartKind.MIRROR:
                    continue
                self._pair(gm, Check.BEAM_ARM, k, seg, j, (0.0 if own else clearance) + margin)
        self.model = gm
        self.data = pin.GeometryData(gm)
        for req, (_, _, _, required) in zip(self.data.collisionRequests, self.pair_info,
                                            strict=True):  # fmt: skip
            req.security_margin = required
            req.gjk_tolerance = 1e-12
        for req in self.data.distanceRequests:
            req.gjk_tolerance = 1e-12
        self.keep_pairs = [i for i, info in enumerate(self.pair_info)
                           if info[0] is Check.BEAM_KEEP_OUT]  # fmt: skip

    def _pair(self, gm: pin.GeometryModel, check: Check, k: int, seg: int, j: int,
              required: float) -> None:  # fmt: skip
        gm.addCollisionPair(pin.CollisionPair(j, seg))
        self.pair_info.append((check, k, j, required))

    def place(self, P: Array) -> None:
        """Put the segments on the polyline ``P`` ((N + 2) x 3, world, m) and the parts at
        the world's last configuration."""
        pin.updateGeometryPlacements(self.world.model, self.world.data, self.model, self.data)
        for k, seg in enumerate(self.segments):
            T, length = capsule_placement(P[k], P[k + 1])
            obj = self.model.geometryObjects[seg]
            obj.geometry.halfLength = length / 2
            M = _se3(T)
            obj.placement = M
            self.data.oMg[seg] = M

    def _records(self, pairs: list[int]) -> list[Clearance]:
        out = []
        for i in pairs:
            check, k, j, required = self.pair_info[i]
            pin.computeDistance(self.model, self.data, i)
            res = self.data.distanceResults[i]
            d = float(res.min_distance)
            if d < required:
                part = self.parts[j]
                out.append(Clearance(
                    check, f"beam[{k}]", part.name, d, required, np.array(res.getNearestPoint2()),
                    np.array(res.getNearestPoint1()), -np.array(res.normal), -1, part.index, k,
                ))  # fmt: skip
        return out

    def violations(self) -> list[Clearance]:
        """Every pair below its required distance (after :meth:`place`)."""
        if not pin.computeCollisions(self.model, self.data, False):
            return []
        hit = [i for i, r in enumerate(self.data.collisionResults) if r.isCollision()]
        return self._records(hit)

    def keep_out_violations(self) -> list[Clearance]:
        """The segment - keep-out pairs below their margin (after :meth:`place`; arm parts ignored)."""
        hit = [i for i in self.keep_pairs if pin.computeCollision(self.model, self.data, i)]
        return self._records(hit)
