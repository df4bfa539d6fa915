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

0. the last mirror is flat: the refit fits a plane, so a curved mirror
   (:attr:`planner.model.mirror.Surface.is_flat` false) is refused at once, every time
   (:func:`planner.calibration.beam.plane_fit_refusal`); the planner goes on with the
   calibration in force;
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
   a fit without it), compared with the residual of the calibration in force over the same
   samples (which has seen some of them, so the test favours keeping it). The held-out
   samples must lie on at least ``MIN_SURFACES`` surfaces (``SpotSample.surface``: the scene
   object the spot landed on; ``MIN_PER_SURFACE`` samples each to count); on *each* of them
   the held-out median must be no worse than the one in force's, and over all of them
   better (medians both under ``EXACT_M`` count as equal). Samples on one plane cannot tell
   a tilted laser from a shifted mirror, so a refit that predicts them well may still be
   wrong everywhere else (version 1 of a cell once put the laser 6 deg and the mirror plane
   36 mm off after 8 samples on one board; every target was "occluded" from then on);
5. the mirror: the inlier fit's covariance (its residual noise, at least ``NOISE_FLOOR_M``),
   propagated to first order to the hit on every mirror, must keep every hit the refit
   plans in a mirror's region of interest ``SIGMA_K`` standard deviations from the edge of
   the mirror's face (the region keeps ``roi_margin`` clear for this), at the inliers'
   joints and the caller's ``planned_q``; a hit it puts outside the region is re-planned,
   not planned, except that at a sample's joints (a spot was seen there) a hit off the
   mirror's face contradicts the measurement.

Units: metres, radians; frames: world, flange, laser as in the scenario.
"""
# long module: the online calibrator: samples, the acceptance rule and the mirror test share its state and its history file

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.beam.graph import BeamModel
from planner.beam.trace import trace_beam
from planner.calibration.beam import (
    FULL_NAMES,
    OBSERVABLE_LASER,
    OBSERVABLE_MIRROR,
    BeamData,
    BeamResult,
    apply_gauge,
    calibrate_beam,
    plane_fit_refusal,
)
from planner.calibration.lsq import exp_T
from planner.calibration.report import beam_document
from planner.errors import BeamrelayError, InputError
from planner.model import d435
from planner.model.system import System
from planner.model.transforms import Array

OUTLIER_MEDIANS = 5.0  # residuals beyond 5 medians are outliers (3.4 sigma of 1-D noise)
FOLDS = 5  # cross-validation folds of the guard
DISTINCT_RAD = 1e-6  # configurations closer than this (max joint difference) count as one
NUMERIC_FLOOR_M = 1e-12  # m: residual medians below this are rounding, all equally good
MAX_SPOT_DISTANCE = 20.0  # m: a spot farther than this from the world origin is not a spot
MIN_SURFACES = 2  # surfaces the held-out samples must span (one plane hides a tilt)
MIN_PER_SURFACE = 2  # held-out samples a surface needs to count (one is not a median)
EXACT_M = 1e-6  # m: held-out medians both below this count as equal (far below camera noise)
SIGMA_K = 3.0  # standard deviations a planned mirror hit must keep inside the usable area
FD_STEP = 1e-6  # rad or m: central-difference step of the hit's parameter Jacobian
#: m: the least spot noise the mirror test believes: the lateral spot noise of our D435 model
#: at 1 m (``d435.SPOT_PX`` at its focal length, measured by ``beamrelay bench detectors``); a
#: fit whose residuals say less (few samples, exact simulated spots) has been lucky, not precise
NOISE_FLOOR_M = d435.SPOT_PX / d435.FOCAL_PX * 1.0


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
    world (m), a placement label, when it was taken (s, any clock) and the surface it lay on
    (a scene object's name; "" unknown: such a sample is fitted, but no surface counts it)."""

    q: Array
    spot_world: Array
    board: int = 0
    t: float = 0.0
    surface: str = ""


def make_sample(
    system: System, q: Any, spot_world: Any, board: int = 0, t: float = 0.0, surface: str = ""
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
    return SpotSample(q_arr, s, int(board), float(t), str(surface))


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
    #: per surface: held-out median (m), the calibration in force's median (m), samples
    surfaces: dict[str, tuple[float, float, int]] = dataclasses.field(default_factory=dict)
    #: smallest margin (m) of a planned mirror hit inside the usable area, less SIGMA_K std
    mirror_margin: float = math.nan
    #: largest propagated standard deviation (m) of a planned mirror hit
    hit_std: float = math.nan

    def figures(self) -> dict[str, Any]:
        """The outcome as flat ``key: value`` figures (mm, counts) for an event line."""
        out: dict[str, Any] = {
            "accepted": self.accepted, "version": self.calibration.version,
            "samples": self.samples, "outliers": len(self.outliers),
            "holdout_mm": 1e3 * self.holdout_median, "current_mm": 1e3 * self.current_median,
            "margin_mm": 1e3 * self.mirror_margin, "hit_std_mm": 1e3 * self.hit_std,
        }  # fmt: skip
        for name, (h, c, n) in self.surfaces.items():
            out[f"surface.{name}"] = f"{1e3 * h:.3f}/{1e3 * c:.3f}mm(n={n})"
        return out | {"reason": self.reason}


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


# long: the acceptance rule's steps (surfaces, fit, held-out medians, mirror test) in the order of the module docstring
def refit(
    samples: Sequence[SpotSample],
    current: Calibration,
    nominal: System,
    *,
    loss_scale: float = 1e-3,
    starts: int = 1,
    planned_q: Sequence[Array] = (),
    first_version: int = 1,
    sigma_k: float = SIGMA_K,
) -> RefitResult:
    """Refit the laser line and last mirror plane to ``samples`` (see the module docstring).

    ``current`` is the calibration in force (the fit starts from it and the guard compares
    against it); ``nominal`` the scenario's system, whose poses fix the gauge; ``planned_q``
    further planned configurations (stacked joints) whose mirror hits the uncertainty must
    keep in the usable area; an accepted version is numbered after ``current``'s and at
    least ``first_version`` (a history that already holds higher numbers).
    """
    k = len(samples)
    if (why := plane_fit_refusal(nominal, nominal.robot_names[-1])) is not None:
        return _refuse(current, k, why)
    need = min_samples(nominal)
    if k < need:
        return _refuse(current, k, f"{k} samples; a refit needs at least {need}")
    all_idx = np.arange(k)
    data = _data(nominal, samples, all_idx)
    if (distinct := _distinct(data.q)) < need:
        return _refuse(current, k, f"the {k} samples were taken at {distinct} distinct joint"
                       f" configurations; a refit needs at least {need}")  # fmt: skip
    labels = [s.surface for s in samples]
    early = {n: (math.nan, math.nan, labels.count(n)) for n in sorted(set(labels) - {""})}
    if (few := _too_few_surfaces(early)) is not None:  # before any fit: cheap and plain
        return _refuse(current, k, few, surfaces=early)
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
    held = _holdout(samples, inl, current.system, nominal, loss_scale)
    q_in, s_in = data.q[inl], data.spots_world[inl]
    cur = ray_distances(current.system, q_in, s_in)
    cur_med = float(np.median(cur))
    allowed = max(cur_med, NUMERIC_FLOOR_M)
    figures: dict[str, Any] = {"outliers": outliers, "current_median": cur_med,
                               "allowed_median": allowed}  # fmt: skip
    if held is None:
        return _refuse(current, k, "a cross-validation fold is degenerate (too few varied"
                       " samples without it)", **figures)  # fmt: skip
    holdout = float(np.median(held))
    figures |= {"holdout_median": holdout,
                "surfaces": per_surface(held, cur, [samples[i].surface for i in inl])}  # fmt: skip
    verdict = _compare(holdout, cur_med, figures["surfaces"], current.version)
    if verdict is not None:
        return _refuse(current, k, verdict, **figures)
    robot = nominal.robot_names[-1]
    L, M = apply_gauge(fit.world_T_laser, fit.flange_T_mirror, nominal.world_T_laser,
                       nominal.robot(robot).mirror.flange_T_mirror)  # fmt: skip
    system = current.system.with_params(L, {robot: M})
    measured = [samples[i].q for i in inl]
    planned = [np.asarray(q, dtype=float) for q in planned_q]
    margin, hit_std, where = mirror_margins(system, fit, measured, planned, sigma_k)
    figures |= {"mirror_margin": margin, "hit_std": hit_std}
    if where is not None:
        return _refuse(current, k, where, **figures)
    version = max(current.version, first_version - 1) + 1
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
        "surfaces": {n: {"holdout_median_m": h, "previous_median_m": c, "samples": m}
                     for n, (h, c, m) in figures["surfaces"].items()},
        "mirror_margin_m": margin,
        "hit_std_max_m": hit_std,
        "sigma_k": sigma_k,
    }  # fmt: skip
    new = Calibration(version, system, doc, k)
    return RefitResult(True, f"version {version} from {len(inl)} of {k} samples", new, k,
                       **figures)  # fmt: skip


def per_surface(
    held: Array, cur: Array, labels: Sequence[str]
) -> dict[str, tuple[float, float, int]]:
    """Held-out and in-force medians (m) and sample count per named surface."""
    out = {}
    for name in sorted({n for n in labels if n}):
        sel = np.array([n == name for n in labels])
        out[name] = (float(np.median(held[sel])), float(np.median(cur[sel])), int(sel.sum()))
    return out


def _too_few_surfaces(surfaces: dict[str, tuple[float, float, int]]) -> str | None:
    """Why the samples' surfaces (name: (.., .., count)) are too few, or None."""
    counted = [n for n, v in surfaces.items() if v[2] >= MIN_PER_SURFACE]
    if len(counted) >= MIN_SURFACES:
        return None
    names = ", ".join(f"{n} ({v[2]})" for n, v in surfaces.items()) or "none known"
    return (f"the samples lie on {len(counted)} surface(s) with at least {MIN_PER_SURFACE}"
            f" each (surfaces: {names}); a refit needs {MIN_SURFACES}: samples on one plane"
            " cannot tell a tilted laser from a shifted mirror")  # fmt: skip


def _compare(
    holdout: float, current: float, surfaces: dict[str, tuple[float, float, int]], version: int
) -> str | None:
    """Why the held-out figures refuse a refit (step 4 of the module docstring), or None."""
    if (few := _too_few_surfaces(surfaces)) is not None:
        return few
    counted = {n: v for n, v in surfaces.items() if v[2] >= MIN_PER_SURFACE}
    for name, (h, c, _) in counted.items():
        if h > max(c, NUMERIC_FLOOR_M, EXACT_M if c <= EXACT_M else 0.0):
            return (f"a refit would be worse out of sample on {name}: held-out median"
                    f" {1e3 * h:.3f} mm > {1e3 * c:.3f} mm of version {version}")  # fmt: skip
    if not (holdout < current or max(holdout, current) <= EXACT_M):
        return (f"a refit would be no better out of sample: held-out median"
                f" {1e3 * holdout:.3f} mm, version {version} gives {1e3 * current:.3f} mm on"
                " the same samples")  # fmt: skip
    return None


# long: a 17-line docstring states the propagation the code follows; the code is 46 lines
def mirror_margins(
    system: System,
    fit: BeamResult,
    measured: Sequence[Array],
    planned: Sequence[Array] = (),
    sigma_k: float = SIGMA_K,
) -> tuple[float, float, str | None]:
    """Step 5: the smallest slack (m) of ``margin + roi_margin - sigma_k * std`` over the
    mirrors, axes and configurations (stacked joints) whose hit the refit puts inside the
    region of interest, the largest hit std (m) there, and why the refit fails (None when
    it does not).

    ``margin`` is the hit's distance inside a mirror's region of interest (``roi_half -
    |uv|`` per axis) in the refit's model, so ``margin + roi_margin`` is its distance from
    the edge of the mirror's face (the area the beam can use at all: the region keeps
    ``roi_margin`` clear along every edge for errors like these); ``std`` is the fit's
    covariance (with its residual noise, but at least ``NOISE_FLOOR_M``) propagated to first
    order to the hit (central differences of the increments the covariance describes, laser
    then last mirror, applied on the right of ``system``'s calibrated poses). A planned hit
    ``sigma_k`` std off then still meets the mirror. A configuration whose hit the refit
    puts outside the region is not planned with it (the planner re-plans that target), so it
    does not count, except that at a ``measured`` configuration (a spot was seen there, so
    the beam met the mirror) a hit off the mirror's face or behind it contradicts the
    measurement and fails."""

    robot = system.robot_names[-1]
    cols = [FULL_NAMES.index(n) for n in fit.std]
    if fit.unit_covariance is not None and math.isfinite(fit.sigma):
        cov = max(fit.sigma, NOISE_FLOOR_M) ** 2 * fit.unit_covariance
    else:
        cov = fit.covariance if fit.covariance is not None else np.diag(
            [v**2 for v in fit.std.values()])  # fmt: skip
    L0, M0 = system.world_T_laser, system.robot(robot).mirror.flange_T_mirror
    band = np.repeat([r.mirror.roi_margin for r in system.robots], 2)

    def trace(q: Array, d: Array) -> Any:
        full = np.zeros(12)
        full[cols] = d
        sys_d = system.with_params(L0 @ exp_T(full[:6]), {robot: M0 @ exp_T(full[6:])})
        return trace_beam(sys_d, q, np.zeros(3))

    worst, worst_std = math.inf, 0.0
    configs = [(q, True) for q in measured] + [(q, False) for q in planned]
    for k, (q, seen) in enumerate(configs):
        tr = trace(q, np.zeros(len(cols)))
        m0 = tr.roi.ravel()
        faces = bool(np.all(tr.front > 0) and np.all(tr.ahead > 0))
        if seen and (not faces or np.any(m0 < -band)):
            return -math.inf, worst_std, (
                f"the refit puts the beam of measured sample {k} off the mirror (a spot was"
                " seen there: the beam met it)")  # fmt: skip
        if not faces or np.any(m0 < 0):
            continue  # not planned with this model: the planner re-plans that target
        J = np.empty((len(m0), len(cols)))
        for c in range(len(cols)):
            e = np.zeros(len(cols))
            e[c] = FD_STEP
            J[:, c] = (trace(q, e).roi.ravel() - trace(q, -e).roi.ravel()) / (2 * FD_STEP)
        std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, cov, J), 0.0))
        if not np.all(np.isfinite(std)):
            return -math.inf, worst_std, f"the hit's uncertainty at configuration {k} is not finite"
        worst_std = max(worst_std, float(std.max()))
        slack = m0 + band - sigma_k * std
        worst = min(worst, float(slack.min()))
        if slack.min() < 0:
            i = int(np.argmin(slack))
            return worst, worst_std, (
                f"its uncertainty could take a planned hit off the mirror: {sigma_k:g} x"
                f" {1e3 * float(std[i]):.2f} mm std at configuration {k} > its"
                f" {1e3 * float(m0[i] + band[i]):.2f} mm from the edge")  # fmt: skip
    return worst, worst_std, None


def _holdout(
    samples: Sequence[SpotSample], inl: Any, start: System, nominal: System, scale: float
) -> Array | None:
    """Held-out residual (m) of each inlier in ``FOLDS``-fold cross-validation, or None when
    a fold cannot be fitted."""
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
    return out
