"""Online refinement of the laser line and mirror plane from executed targets (paper Eq. 10).

Every executed target whose spot the camera measured at rest is one beam-calibration sample:
the stacked joints ``q`` of every robot (rad) and the spot in the world (m; a camera-frame
spot is mapped through the calibrated camera pose by the caller). The spot is a 3D point, so
the surface it landed on is not an unknown (as in ``beamrelay calibrate beam``); ``board`` is
only a placement label.

:func:`refit` re-runs :func:`planner.calibration.beam.calibrate_beam` on the samples, starting
from the calibration in force: the unknowns are the *last* robot's mirror plane, plus the
laser line when the chain has one robot (the spot is measured after the whole chain, so with
N > 1 only the last mirror is seen; the earlier ones stay as calibrated). Only the observable
directions are solved (N = 1: 7 of 12 pose parameters), and the gauge is re-fixed against the
scenario's nominal poses, so repeated refits never drift along the unobservable directions.

Steps, each of which may refuse (the calibration in force is kept, the reason is given):

1. at least :func:`min_samples` samples at that many distinct configurations: one per
   unknown, 7 for N = 1 (2 equations per spot: 4 spots determine the 7 unknowns, but then
   a bad spot cannot show in the residuals, and the cross-validation below fits 4/5 of the
   samples; with 5 samples a refit that the held-out test accepted was seen to put the
   spots 8.5 mm off where the scenario's calibration gave 6 mm);
2. a least-squares fit gives the residual level, then a robust (Cauchy) fit with that
   median residual as its scale (at least ``loss_scale``); samples whose residual exceeds
   both ``OUTLIER_MEDIANS`` times the median residual (times ``sqrt(m / (m - p))``, the
   in-sample shrinkage of residuals with m equations and p unknowns) and ``loss_scale`` are
   outliers and dropped (5 medians: 3.4 sigma when the noise is mostly along one axis, as a
   depth error seen across the beam is; 5.9 sigma for isotropic 2-D noise);
3. a plain least-squares fit of the inliers (its covariance gives the parameter std);
4. the guard: a ``FOLDS``-fold cross-validation gives each inlier's held-out residual (from
   a fit without it); the refit is accepted only if their median is at most the median
   residual of the calibration in force over the same samples: a new version must predict
   spots it was not fitted to at least as well as the one in force does (which has seen
   some of them, so the test favours keeping it); medians under ``NUMERIC_FLOOR_M`` count
   as equal.

Units: metres, radians; frames: world, flange, laser as in the scenario.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.beam.graph import BeamModel
from planner.calibration.beam import (
    OBSERVABLE_LASER,
    OBSERVABLE_MIRROR,
    BeamData,
    BeamResult,
    apply_gauge,
    calibrate_beam,
)
from planner.calibration.report import beam_document
from planner.errors import BeamrelayError, InputError
from planner.model.system import System
from planner.model.transforms import Array

OUTLIER_MEDIANS = 5.0  # residuals beyond 5 medians are outliers (3.4 sigma of 1-D noise)
FOLDS = 5  # cross-validation folds of the guard
DISTINCT_RAD = 1e-6  # configurations closer than this (max joint difference) count as one
NUMERIC_FLOOR_M = 1e-12  # m: residual medians below this are rounding, all equally good
MAX_SPOT_DISTANCE = 20.0  # m: a spot farther than this from the world origin is not a spot


def n_unknowns(system: System) -> int:
    """Observable parameters an online refit solves: laser line (4) + mirror plane (3) for
    one robot, the last mirror's plane (3) for a longer chain."""
    return len(OBSERVABLE_MIRROR) + (len(OBSERVABLE_LASER) if system.n_robots == 1 else 0)


def min_samples(system: System) -> int:
    """Fewest samples a refit accepts: one per unknown (twice the equations needed), so
    that every cross-validation training set is still over-determined."""
    return n_unknowns(system)


@dataclass(frozen=True)
class SpotSample:
    """One measured spot: stacked joints of every robot (rad, robot order), the spot in the
    world (m), a placement label, and when it was taken (s, any clock)."""

    q: Array
    spot_world: Array
    board: int = 0
    t: float = 0.0


def make_sample(
    system: System, q: Any, spot_world: Any, board: int = 0, t: float = 0.0
) -> SpotSample:
    """A validated :class:`SpotSample`; ``q`` is ``{robot: joints}`` or the stacked vector.

    Raises InputError naming the field for a wrong shape, a non-finite value, joints outside
    the robots' position limits or a spot farther than ``MAX_SPOT_DISTANCE`` m (wrong units).
    """
    try:
        if isinstance(q, dict):
            q_arr = system.stack_q({k: np.asarray(v, dtype=float) for k, v in q.items()})
        else:
            q_arr = np.asarray(q, dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"not joint values: {exc}", "q") from None
    try:
        s = np.asarray(spot_world, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"not a spot: {exc}", "spot_world") from None
    if q_arr.shape != (system.nq,) or not np.all(np.isfinite(q_arr)):
        raise InputError(f"expected {system.nq} finite joint values (rad), got {q_arr.shape}", "q")
    lower = np.concatenate([r.limits.lower for r in system.robots])
    upper = np.concatenate([r.limits.upper for r in system.robots])
    if np.any(q_arr < lower) or np.any(q_arr > upper):
        raise InputError("joints outside the position limits (rad)", "q")
    if s.shape != (3,) or not np.all(np.isfinite(s)):
        raise InputError(f"expected a finite 3D spot (m), got shape {s.shape}", "spot_world")
    if float(np.linalg.norm(s)) > MAX_SPOT_DISTANCE:
        raise InputError(
            f"spot {float(np.linalg.norm(s)):.3g} m from the world origin (metres expected)",
            "spot_world",
        )
    return SpotSample(q_arr, s, int(board), float(t))


@dataclass(frozen=True)
class Calibration:
    """The calibration in force: ``version`` (0 = the scenario's), its system, its YAML
    document (None for version 0) and the number of samples it was fitted to."""

    version: int
    system: System
    document: dict[str, Any] | None = None
    samples: int = 0


@dataclass(frozen=True)
class RefitResult:
    """Outcome of :func:`refit`. ``calibration`` is the one in force afterwards (the new one
    if ``accepted``, else the previous); ``reason`` says why it was refused, or what it
    did. Residual medians in metres (NaN when not computed); ``outliers`` index the samples."""

    accepted: bool
    reason: str
    calibration: Calibration
    samples: int
    outliers: tuple[int, ...] = ()
    holdout_median: float = math.nan
    current_median: float = math.nan
    allowed_median: float = math.nan


def ray_distances(system: System, q: Array, spots: Array) -> Array:
    """Distance (m) from each spot (K, 3, world) to the last ray of the beam at ``q`` (K, nq)."""
    model = BeamModel(system)
    return np.array([model.trace(qk, sk).error for qk, sk in zip(q, spots, strict=True)])


def _data(system: System, samples: Sequence[SpotSample], idx: Any) -> BeamData:
    return BeamData(
        robot=system.robot_names[-1],
        q=np.array([samples[i].q for i in idx]),
        spots_world=np.array([samples[i].spot_world for i in idx]),
        boards=np.array([samples[i].board for i in idx], dtype=int),
    )


def _fit(data: BeamData, start: System, loss: str, scale: float, starts: int) -> BeamResult:
    return calibrate_beam(data, start, loss=loss, loss_scale=scale, starts=starts)


def _refuse(current: Calibration, k: int, reason: str, **kw: Any) -> RefitResult:
    return RefitResult(False, reason, current, k, **kw)


def _distinct(q: Array) -> int:
    keys = {tuple(np.round(row / DISTINCT_RAD).astype(np.int64)) for row in q}
    return len(keys)


def refit(
    samples: Sequence[SpotSample],
    current: Calibration,
    nominal: System,
    *,
    loss_scale: float = 1e-3,
    starts: int = 1,
) -> RefitResult:
    """Refit the laser line and last mirror plane to ``samples`` (see the module docstring).

    ``current`` is the calibration in force (the fit starts from it and the guard compares
    against it); ``nominal`` the scenario's system, whose poses fix the gauge.
    """
    k = len(samples)
    need = min_samples(nominal)
    if k < need:
        return _refuse(current, k, f"{k} samples; a refit needs at least {need}")
    all_idx = np.arange(k)
    data = _data(nominal, samples, all_idx)
    if (distinct := _distinct(data.q)) < need:
        return _refuse(current, k, f"the {k} samples were taken at {distinct} distinct joint"
                       f" configurations; a refit needs at least {need}")  # fmt: skip
    m, p = 2 * k, n_unknowns(nominal)
    try:
        plain = _fit(data, current.system, "none", loss_scale, starts)
        scale = max(loss_scale, float(np.median(plain.residuals)))
        robust = _fit(data, current.system, "cauchy", scale, starts)
    except BeamrelayError as exc:
        return _refuse(current, k, f"refit failed: {exc}")
    r = robust.residuals
    bad = (r > OUTLIER_MEDIANS * math.sqrt(m / (m - p)) * float(np.median(r))) & (r > loss_scale)
    outliers = tuple(int(i) for i in np.nonzero(bad)[0])
    inl = all_idx[~bad]
    if len(inl) < need:
        return _refuse(current, k, f"{len(outliers)} of {k} samples are outliers; too few left",
                       outliers=outliers)  # fmt: skip
    try:
        fit = _fit(_data(nominal, samples, inl), current.system, "none", loss_scale, 1)
    except BeamrelayError as exc:
        return _refuse(current, k, f"refit of the inliers failed: {exc}", outliers=outliers)
    holdout = _holdout(samples, inl, current.system, nominal, loss_scale)
    q_in, s_in = data.q[inl], data.spots_world[inl]
    cur_med = float(np.median(ray_distances(current.system, q_in, s_in)))
    allowed = max(cur_med, NUMERIC_FLOOR_M)
    figures = {"outliers": outliers, "current_median": cur_med, "allowed_median": allowed}
    if holdout is None:
        return _refuse(current, k, "a cross-validation fold is degenerate (too few varied"
                       " samples without it)", **figures)  # fmt: skip
    if not holdout <= allowed:
        return _refuse(current, k, f"a refit would be worse out of sample: held-out median"
                       f" {1e3 * holdout:.3f} mm > {1e3 * allowed:.3f} mm allowed (the version"
                       f" {current.version} model gives {1e3 * cur_med:.3f} mm on the same"
                       " samples)", holdout_median=holdout, **figures)  # fmt: skip
    robot = nominal.robot_names[-1]
    L, M = apply_gauge(fit.world_T_laser, fit.flange_T_mirror, nominal.world_T_laser,
                       nominal.robot(robot).mirror.flange_T_mirror)  # fmt: skip
    system = current.system.with_params(L, {robot: M})
    version = current.version + 1
    result = dataclasses.replace(fit, world_T_laser=L, flange_T_mirror=M)
    doc = beam_document(result, dataset=f"online refinement, version {version}")
    doc["report"]["online"] = {
        "version": version,
        "samples": k,
        "inliers": len(inl),
        "outliers": list(outliers),
        "holdout_median_m": holdout,
        "previous_median_m": cur_med,
        "allowed_median_m": allowed,
        "previous_version": current.version,
    }
    new = Calibration(version, system, doc, k)
    return RefitResult(True, f"version {version} from {len(inl)} of {k} samples", new, k,
                       outliers, holdout, cur_med, allowed)  # fmt: skip


def _holdout(
    samples: Sequence[SpotSample], inl: Any, start: System, nominal: System, scale: float
) -> float | None:
    """Median held-out residual (m) of ``FOLDS``-fold cross-validation over the inliers, or
    None when a fold cannot be fitted."""
    folds = min(FOLDS, len(inl))
    out = np.empty(len(inl))
    robot = nominal.robot_names[-1]
    for f in range(folds):
        test = np.arange(len(inl)) % folds == f
        train = inl[~test]
        if len(train) < min_samples(nominal) - 1:
            return None
        try:
            res = _fit(_data(nominal, samples, train), start, "none", scale, 1)
        except BeamrelayError:
            return None
        sys_f = start.with_params(res.world_T_laser, {robot: res.flange_T_mirror})
        t_idx = inl[test]
        q = np.array([samples[i].q for i in t_idx])
        s = np.array([samples[i].spot_world for i in t_idx])
        out[test] = ray_distances(sys_f, q, s)
    return float(np.median(out))
