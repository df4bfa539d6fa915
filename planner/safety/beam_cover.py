"""Conservative advancement for the laser-on beam check: exact checks only where needed.

The dense check of a trajectory (:func:`~planner.safety.trajectory.check_beam_samples`)
must clear the beam against every arm part and keep-out volume at every laser-on sample.
Measuring every pair exactly (coal) at every sample costs ~0.2 ms a sample. Instead, a
sample checked exactly (an *anchor*) also measures every beam pair's distance ``d_p``;
a later sample m is then certified without coal when, for every pair p (segment k, part j),

    d_p(anchor) - move_k(m) - reach_j . |q_m - q_anchor|  >  required_p + EPS

``move_k`` is the largest displacement of segment k's two end points between the two
samples (exact: the beams of all samples are traced in one batch; every point of a segment
moves by at most that much), ``reach_j . |dq|`` bounds how far any point of part j moves
over the joint step (:func:`~planner.safety.sweep.reach_table`, configuration independent;
0 for keep-out volumes). By the triangle inequality the pair's distance at m is at least
the left-hand side, so it keeps its required distance; a sample not certified becomes the
next anchor. The result equals the sample-by-sample check's. World frame, metres, rad.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from planner.model.transforms import Array
from planner.safety.model import Safety, Violation
from planner.safety.sweep import reach_table

#: m: certified margins must exceed this (covers coal's distance error, ~1e-7 m at worst
#: for near-parallel capsules, with room to spare)
EPS = 1e-6
Mask = npt.NDArray[np.bool_]
#: samples bounded per vectorised step ahead of an anchor
CHUNK = 512


class PairTable(NamedTuple):
    """The beam pairs of a :class:`Safety`: per pair its segment ``k``, required distance
    (m) and the reach row of its part (nq, m/rad; zeros for a keep-out volume)."""

    segment: Array
    required: Array
    reach: Array


def pair_table(safety: Safety) -> PairTable:
    """The beam pairs' segments, required distances and part reach rows."""
    bp = safety.beam_pairs
    R = reach_table(safety.world)
    k = np.array([info[1] for info in bp.pair_info], dtype=int)
    req = np.array([info[3] for info in bp.pair_info], dtype=float)
    reach = np.array([R[bp.parts[info[2]].index] for info in bp.pair_info]).reshape(len(k), -1)
    return PairTable(k, req, reach)


def pair_slack(safety: Safety, table: PairTable) -> Array:
    """Each beam pair's distance minus its required distance (m) at the last
    :meth:`Safety.beam` placement (parts and segments as placed)."""
    bp = safety.beam_pairs
    if not len(table.segment):
        return np.zeros(0)
    pin.computeDistances(bp.model, bp.data)
    d = np.array([r.min_distance for r in bp.data.distanceResults], dtype=float)
    return d - table.required


def covered(table: PairTable, slack: Array, q0: Array, P0: Array, Q: Array, P: Array) -> Mask:
    """Which samples (joints ``Q``: M x nq rad, beam polylines ``P``: M x (N + 2) x 3 m) the
    anchor (``q0``, ``P0``, pair ``slack`` m) certifies (see the module docstring)."""
    if not len(slack):
        return np.ones(len(Q), dtype=bool)
    ends = np.linalg.norm(P - P0[None], axis=2)  # (M, N + 2): end point displacements
    seg = np.maximum(ends[:, :-1], ends[:, 1:])  # (M, N + 1)
    parts = np.abs(Q - q0[None]) @ table.reach.T  # (M, pairs)
    bound = seg[:, table.segment] + parts
    return np.asarray(np.all(bound < (slack - EPS)[None], axis=1), dtype=bool)


def advance(
    table: PairTable, slack: Array, rows: npt.NDArray[np.intp], m: int, Q: Array, P: Array
) -> int:
    """Index into ``rows`` of the first row after ``m`` that the anchor at ``rows[m]`` does
    not certify (``len(rows)`` when it certifies them all); ``Q`` and ``P`` are indexed by
    the row numbers."""
    a = rows[m]
    start = m + 1
    while start < len(rows):
        chunk = rows[start : start + CHUNK]
        ok = covered(table, slack, Q[a], P[a], Q[chunk], P[chunk])
        if not ok.all():
            return start + int(np.argmin(ok))
        start += len(chunk)
    return len(rows)


def coverable(safety: Safety) -> bool:
    """Whether the beam rules of ``safety`` are all pair distances: a camera on a flange
    (its lens posed by the configuration) is checked at every sample instead."""
    cam = safety.system.camera
    return cam is None or cam.robot is None


def aperture_mask(safety: Safety, P: Array) -> Mask:
    """(M,) rows of beams ``P`` (M x (N + 2) x 3, world, m) entering the laser aperture or a
    fixed camera's lens (the rule of :meth:`Safety.apertures_batch`, every row, widened by
    :data:`EPS` so that rounding can only add rows)."""
    from planner.safety.model import aperture_hits

    s, system = safety.settings, safety.system
    r = s.return_radius
    hit = aperture_hits(P, system.world_T_laser, r, s.return_cone, 1, EPS).any(axis=1)
    cam = system.camera
    if cam is not None and cam.robot is None:
        hit |= aperture_hits(P, cam.world_T_camera, r, s.lens_cone, 0, EPS).any(axis=1)
    return np.asarray(hit, dtype=bool)


def configs(safety: Safety, Q: npt.ArrayLike, P: npt.ArrayLike) -> list[Violation | None]:
    """``safety.config(Q[i], P[i])`` for every row (joints M x nq rad, beam polylines
    M x (N + 2) x 3 m), measuring with coal only the rows that conservative advancement
    from the last clean measured row cannot certify: every arm pair (its
    :func:`~planner.safety.sweep.pair_weights` bound) and every beam pair (module docstring)
    keeps its distance, and the beam enters no aperture. A certified row breaks no rule, so
    its entry is None as ``config`` would give."""
    from planner.safety.sweep import pair_weights

    Q, P = np.asarray(Q, dtype=float), np.asarray(P, dtype=float)
    M = len(Q)
    finite = np.all(np.isfinite(Q), axis=1) & np.all(np.isfinite(P), axis=(1, 2))
    if not coverable(safety) or not finite.all():
        return [safety.config(q, p) for q, p in zip(Q, P, strict=True)]
    world, table = safety.world, pair_table(safety)
    W = pair_weights(world)
    arm_req = np.array([safety.required(k) for k in world.pair_kinds])
    blocked = aperture_mask(safety, P)
    out: list[Violation | None] = [None] * M
    i = 0
    while i < M:
        out[i] = safety.config(Q[i], P[i])
        if out[i] is not None or blocked[i]:
            i += 1
            continue
        beam_slack = pair_slack(safety, table)
        arm_slack = np.zeros(0)
        if len(arm_req):
            pin.computeDistances(world.geom_model, world.geom_data)
            d = np.array([r.min_distance for r in world.geom_data.distanceResults])
            arm_slack = d - arm_req
        j = i + 1
        while j < M:
            rows = np.arange(j, min(j + CHUNK, M))
            ok = covered(table, beam_slack, Q[i], P[i], Q[rows], P[rows]) & ~blocked[rows]
            if len(arm_slack):
                moved = np.abs(Q[rows] - Q[i]) @ W.T
                ok = ok & np.all(moved < (arm_slack - EPS)[None], axis=1)
            if not ok.all():
                j += int(np.argmin(ok))
                break
            j += len(rows)
        i = j
    return out
