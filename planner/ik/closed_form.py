"""Exact closed-form beam IK: the explicit family of mirror poses that hit a target.

For N = 1 every solution is a member of a 4-parameter family: choose the hit point
``h = p0 + s v0`` on the incoming beam; the mirror normal is then the bisector of ``-v0``
and ``target - h``; the roll ``psi`` of the mirror about its normal and the in-plane offset
``(u, v)`` of ``h`` from the mirror centre are free. ``world_T_flange = world_T_mirror @
inv(flange_T_mirror)`` and the UR analytic IK gives up to 8 joint branches, each hitting the
target to machine precision. For N > 1 the intermediate hit points are free too (seeded at
the mirrors' current centres); every bounce normal is again a bisector.

Nothing here assumes a flat mirror: the mirror is placed through the seam
(:meth:`planner.model.mirror.Mirror.place`), which puts the face point over ``(u, v)`` on
the hit with the bisector as the face's normal there, whatever the face's shape (a flat face
has the same normal everywhere, a curved one tilts its frame to match); an offset over which
the face has no point is skipped like a pose without IK. Every member is traced again by
the caller before it is accepted.

:class:`ClosedForm` searches (s, psi, u, v) in a fixed priority order, nearest the previous
configuration first, and returns the first member inside the joint limits and the ROI, or
the reason none is (with the numbers). World frame, metres, radians.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from planner.beam.trace import mirror_poses
from planner.ik.safe_members import MemberSafety
from planner.ik.search_stats import SearchStats
from planner.model.kinematics import RobotKinematics
from planner.model.status import Reason
from planner.model.system import System
from planner.model.transforms import Array, inv_T

TWO_PI = 2.0 * np.pi
_DEGENERATE = 1e-9  # |d_out - d_in| below this: grazing, the bisector is undefined
_S_OFFSETS = (0.0, 0.03, -0.03, 0.08, -0.08, 0.15, -0.15, 0.25, -0.25, 0.4, -0.4, 0.6, -0.6)
_PSI = tuple(np.pi / 6 * k for k in (0, 1, -1, 2, -2, 3, -3, 4, -4, 5, -5, 6))
_H_STEPS = (0.0, 0.05, 0.12, 0.25)
_RING = tuple(np.linspace(0.0, TWO_PI, 8, endpoint=False))  # (u, v) ring angles, rad
_AXES = np.vstack([np.eye(3), -np.eye(3)])
_NOMINAL_TOL = 0.01  # a URDF arm whose flange is within 1 cm of the nominal UR5e


@lru_cache(maxsize=4)
def _mid_steps(n_mid: int) -> tuple[Array, list[tuple[int, ...]], Array]:
    """Offsets (metres) tried for the N - 1 intermediate hit points: the step vectors, the
    25 cheapest index combinations (nearest the current centres first) and their costs."""
    steps = np.vstack([np.zeros(3)] + [a * e for a in _H_STEPS[1:] for e in _AXES])
    norms = np.linalg.norm(steps, axis=1)
    combos = list(itertools.product(range(len(steps)), repeat=n_mid)) if n_mid else [()]
    combos = sorted(combos, key=lambda ks: sum(float(norms[k]) for k in ks))[:25]
    cost = np.array([sum(float(norms[k]) for k in ks) for ks in combos])
    return steps, combos, cost


class Stage(NamedTuple):
    s_offsets: tuple[float, ...]
    psi: tuple[float, ...]
    uv_scale: tuple[float, ...]  # ring radii; as fractions of roi_half, or metres if outside


@lru_cache(maxsize=8)
def _nominal_ur5e() -> RobotKinematics:
    return RobotKinematics.ur5e()


def seed_kinematics(kin: RobotKinematics) -> RobotKinematics | None:
    """The model whose analytic IK seeds ``kin``: itself, the nominal UR5e for a calibrated
    UR5e URDF (flange within 1 cm of nominal at test poses), or None (IPOPT only)."""
    if kin.has_analytic_ik:
        return kin
    if kin.nq != 6:
        return None
    nominal = _nominal_ur5e()
    rng = np.random.default_rng(0)
    for q in rng.uniform(-np.pi, np.pi, (8, 6)):
        if np.abs(kin.fk(q)[:3, 3] - nominal.fk(q)[:3, 3]).max() > _NOMINAL_TOL:
            return None
    return nominal


def bisector(d_in: Array, d_out: Array) -> Array | None:
    """Unit mirror normal reflecting unit direction ``d_in`` into ``d_out``, None if grazing."""
    n = d_out - d_in
    norm = float(np.linalg.norm(n))
    return None if norm < _DEGENERATE else n / norm


def branches_within_limits(
    branches: Array, q_ref: Array, lower: Array, upper: Array
) -> tuple[Array, float]:
    """Branches (each joint shifted by 2 pi k toward ``q_ref``) within limits, nearest
    ``q_ref`` first, and the smallest limit violation (rad) over all branches (0 if any is
    within the limits)."""
    q = branches + TWO_PI * np.round((q_ref - branches) / TWO_PI)
    q = np.where(q > upper, q - TWO_PI, q)
    q = np.where(q < lower, q + TWO_PI, q)
    viol = np.maximum(q - upper, 0.0).max(axis=1) + np.maximum(lower - q, 0.0).max(axis=1)
    ok = viol <= 0.0
    if not ok.any():
        return q[:0], float(viol.min())
    dist = ((q[ok] - q_ref) ** 2).sum(axis=1)
    return q[ok][np.argsort(dist, kind="stable")], 0.0


def pick_branch(
    branches: Array, q_ref: Array, lower: Array, upper: Array
) -> tuple[Array | None, float]:
    """Branch (each joint shifted by 2 pi k toward ``q_ref``) nearest ``q_ref`` within limits.

    Returns (q, 0) or (None, smallest limit violation in rad over the branches)."""
    qs, viol = branches_within_limits(branches, q_ref, lower, upper)
    return (qs[0], 0.0) if len(qs) else (None, viol)


class ClosedFormResult(NamedTuple):
    q: Array | None  # stacked joints of the chosen member, or None
    reason: Reason | None  # failure reason when q is None
    evidence: dict[str, object]
    members: int  # family members tried


class ClosedForm:
    """The closed-form family search for one system (requires a seed model for every arm)."""

    def __init__(self, system: System, safety: MemberSafety | None = None) -> None:
        self.safety = safety
        seeds = [seed_kinematics(r.kinematics) for r in system.robots]
        if any(s is None for s in seeds):
            raise ValueError("closed form needs an analytic seed model for every robot")
        self.system = system
        self.seeds: list[RobotKinematics] = [s for s in seeds if s is not None]
        self.exact = all(s is r.kinematics for s, r in zip(self.seeds, system.robots, strict=True))
        self.base_T_world = [inv_T(r.world_T_base) for r in system.robots]
        self.mirror_T_flange = [inv_T(r.mirror.flange_T_mirror) for r in system.robots]
        self.p0 = system.world_T_laser[:3, 3].copy()
        self.v0 = system.world_T_laser[:3, 2] / np.linalg.norm(system.world_T_laser[:3, 2])
        self.roi_half = [r.mirror.roi_half for r in system.robots]
        self.slices = []
        i = 0
        for r in system.robots:
            self.slices.append(slice(i, i + r.nq))
            i += r.nq

    # --------------------------------------------------------------------------------------
    def _combos(
        self, s0: float, centres: list[Array], s_offsets: tuple[float, ...]
    ) -> Iterator[list[Array]]:
        """Hit-point lists [h_1, ..., h_N] in priority order (nearest the seed first), lazily:
        the common case uses the first one, so only the order is computed up front."""
        steps, mids, mid_cost = _mid_steps(len(centres) - 1)
        offsets = np.asarray(s_offsets, dtype=float)
        cost = np.abs(offsets)[:, None] + mid_cost[None, :]
        n_mids = len(mids)
        for flat in np.argsort(cost, axis=None, kind="stable"):
            i, j = divmod(int(flat), n_mids)
            s = max(s0 + offsets[i], 0.02)
            yield [self.p0 + s * self.v0] + [
                c + steps[k] for c, k in zip(centres[1:], mids[j], strict=True)
            ]

    def _normals(self, hits: list[Array], target: Array) -> tuple[list[Array] | None, Array]:
        d_in = self.v0
        normals = []
        for i, h in enumerate(hits):
            nxt = hits[i + 1] if i + 1 < len(hits) else target
            d_out = nxt - h
            d_out = d_out / np.linalg.norm(d_out)
            n = bisector(d_in, d_out)
            if n is None:
                return None, d_out
            normals.append(n)
            d_in = d_out
        return normals, d_in

    def _candidates(
        self,
        i: int,
        T_args: tuple[Array, Array, Array],
        stage: Stage,
        inside: bool,
        q_ref: Array,
        stats: SearchStats,
    ) -> Iterator[tuple[Array, Array]]:
        """Robot i's joint solutions (and hit offsets uv) placing its mirror on the hit, lazily:
        by roll psi, then offset uv, then branch (within limits, nearest ``q_ref`` first)."""
        h, n, x_ref = T_args
        r = self.system.robots[i]
        hu, hv = self.roi_half[i]
        uvs = [np.zeros(2)] if inside and stage.uv_scale == (0.0,) else []
        for a in stage.uv_scale:
            for th in _RING:
                if a == 0.0:
                    continue
                uv = (
                    np.array([a * hu * np.cos(th), a * hv * np.sin(th)])
                    if inside
                    else (a * np.array([np.cos(th), np.sin(th)]))
                )
                if inside or np.any(np.abs(uv) > [hu, hv]):
                    uvs.append(uv)
        for psi in stage.psi:
            for uv in uvs:
                T = r.mirror.place(h, n, x_ref, psi, uv)
                if not np.isfinite(T).all():  # the face has no point over uv
                    stats.no_ik += 1
                    continue
                base_T_flange = self.base_T_world[i] @ T @ self.mirror_T_flange[i]
                branches = self.seeds[i].analytic_ik(base_T_flange)
                if not branches:
                    stats.no_ik += 1
                    continue
                qs, viol = branches_within_limits(
                    np.array(branches), q_ref, r.limits.lower, r.limits.upper
                )
                if not len(qs):
                    stats.limits += 1
                    stats.min_limit_violation = min(stats.min_limit_violation, viol)
                    continue
                for q in qs:
                    yield q, uv

    def _run(
        self,
        target: Array,
        normal: Array | None,
        q_prev: Array,
        max_incidence: float | None,
        stage: Stage,
        inside: bool,
        stats: SearchStats,
    ) -> Array | None:
        prev = mirror_poses(self.system, q_prev)
        centres = [M[:3, 3] for M in prev]
        s0 = float(self.v0 @ (centres[0] - self.p0))
        # second seed: the beam point nearest robot 0's shoulder (the reach is centred there)
        shoulder = self.system.robots[0].world_T_base @ np.array([0.0, 0.0, 0.163, 1.0])
        ds = float(self.v0 @ (shoulder[:3] - self.p0)) - s0
        offsets = stage.s_offsets + tuple(ds + x for x in (0.0, 0.1, -0.1, 0.25, -0.25))
        for hits in self._combos(s0, centres, offsets):
            stats.members += 1
            normals, d_last = self._normals(hits, target)
            if normals is None:
                stats.grazing += 1
                continue
            if normal is not None and max_incidence is not None:
                inc = float(np.arccos(min(abs(float(d_last @ normal)), 1.0)))
                if inc > max_incidence:
                    stats.incidence += 1
                    stats.min_incidence = min(stats.min_incidence, inc)
                    continue
            gens = [
                self._candidates(i, (hits[i], normals[i], prev[i][:3, 0]), stage, inside,
                                 q_prev[self.slices[i]], stats)
                for i in range(len(hits))
            ]  # fmt: skip
            firsts = []
            for gen in gens:
                first = next(gen, None)
                if first is None:
                    break
                firsts.append(first)
            else:
                q = self._safe(gens, firsts, hits, target, stats)
                if q is not None:
                    stats.evidence = {"s": float(self.v0 @ (hits[0] - self.p0)),
                                      "uv_last": firsts[-1][1].tolist()}  # fmt: skip
                    return q
        return None

    def _safe(
        self,
        gens: list[Iterator[tuple[Array, Array]]],
        firsts: list[tuple[Array, Array]],
        hits: list[Array],
        target: Array,
        stats: SearchStats,
    ) -> Array | None:
        """The member's first configuration that passes the safety rules (the first one when
        there are none), or None with the rejection counted in ``stats``."""
        q = np.concatenate([f[0] for f in firsts])
        if self.safety is None:
            return q
        return self.safety.first_safe(q, gens, firsts, hits, target, stats)

    def search(
        self, target: Array, normal: Array | None, q_prev: Array, max_incidence: float | None = None
    ) -> ClosedFormResult:
        """First feasible family member nearest ``q_prev``, or the failure reason and evidence.

        Stage 1: u = v = 0 over (s, psi); stage 2: (u, v) inside the ROI; stage 3 (diagnosis):
        (u, v) outside the ROI, which turns "no IK" into ``outside_roi``.
        """
        stats = SearchStats()
        target = np.asarray(target, dtype=float)
        full = Stage(_S_OFFSETS, _PSI, (0.0,))
        q = self._run(target, normal, q_prev, max_incidence, full, True, stats)
        if q is not None:
            return ClosedFormResult(q, None, _with_unsafe(stats), stats.members)
        if stats.grazing == stats.members:
            d = target - self.p0
            off = float(np.linalg.norm(d - (d @ self.v0) * self.v0))
            why = ("target lies on the incoming beam past every reachable hit point: the mirror"
                   " would be hit edge-on (front = -n.v = 0)")  # fmt: skip
            evidence = {"target_off_beam_m": off, "why": why}
            return ClosedFormResult(None, Reason.BACK_FACE, evidence, stats.members)
        coarse = Stage(_S_OFFSETS, _PSI[::2], (0.5, 1.0))
        q = self._run(target, normal, q_prev, max_incidence, coarse, True, stats)
        if q is not None:
            return ClosedFormResult(q, None, _with_unsafe(stats), stats.members)
        return self._failure(target, normal, q_prev, max_incidence, stats)

    def _failure(
        self, target: Array, normal: Array | None, q_prev: Array, max_incidence: float | None,
        stats: SearchStats,
    ) -> ClosedFormResult:  # fmt: skip
        """Why stages 1 and 2 found no member (``stats``): the safety rule that turned down
        the least unsafe one, joint limits, incidence, or (stage 3, probing outside the ROI)
        an offset the ROI does not allow; else unreachable."""
        if stats.least_unsafe is not None:
            v = stats.least_unsafe
            evidence = {**v.evidence, "members_unsafe": stats.unsafe,
                        "unsafe_by_reason": dict(stats.by_reason)}  # fmt: skip
            return ClosedFormResult(None, Reason(v.reason), evidence, stats.members)
        if stats.limits:
            return ClosedFormResult(
                None,
                Reason.JOINT_LIMITS,
                {
                    "min_limit_violation_rad": stats.min_limit_violation,
                    "members_out_of_limits": stats.limits,
                },
                stats.members,
            )
        if stats.incidence and not stats.no_ik:
            return ClosedFormResult(
                None,
                Reason.UNREACHABLE,
                {
                    "min_incidence_deg": float(np.degrees(stats.min_incidence)),
                    "max_incidence_deg": float(np.degrees(max_incidence or 0.0)),
                },
                stats.members,
            )
        roi = float(max(np.max(h) for h in self.roi_half))
        outside = Stage(_S_OFFSETS, _PSI[::2], (1.5 * roi + 0.005, 2 * roi + 0.02, 0.1))
        probe = SearchStats()
        if self._run(target, normal, q_prev, None, outside, False, probe) is not None:
            uv = probe.evidence.get("uv_last", [0.0, 0.0])
            evidence = {
                "offset_needed_mm": 1e3 * float(np.linalg.norm(np.asarray(uv))),
                "roi_half_mm": [1e3 * float(x) for x in self.roi_half[-1]],
                "why": "the arm reaches a mirror pose on this beam only with the hit off the ROI",
            }
            return ClosedFormResult(
                None, Reason.OUTSIDE_ROI, evidence, stats.members + probe.members
            )
        distances = [float(np.linalg.norm(np.cross(r.world_T_base[:3, 3] - self.p0, self.v0)))
                     for r in self.system.robots]  # fmt: skip
        evidence = {"members_without_ik": stats.no_ik, "beam_distance_to_base_m": distances}
        return ClosedFormResult(None, Reason.UNREACHABLE, evidence, stats.members + probe.members)


def _with_unsafe(stats: SearchStats) -> dict[str, object]:
    """Success evidence, with the count of members the safety rules turned down."""
    if not stats.unsafe:
        return stats.evidence
    return {**stats.evidence, "safety_rejected": stats.unsafe}
