"""One trial of ``study experiments``: hidden truth, calibration, plan, execute, measure.

Per trial (seeded, independent of how many run and where):

1. a hidden TRUE geometry (:func:`~planner.studies.experiments_setup.draw_truth` at the
   :class:`~planner.studies.experiments_setup.Unknowns` levels); the planner starts from
   the nominal scenario;
2. calibration on the simulated cell (:func:`~planner.studies.experiments_cell.calibrate_cell`:
   20 hand-eye poses; 16 poses x 3 boards for laser + mirror; D435 noise);
3. per experiment run (:func:`~planner.studies.experiments_setup.experiments`): the camera
   measures the targets (D435 corner noise; with ``Effects.cloud_targets`` the curve, face
   and finger targets are picked in its point cloud with SVD normals,
   :mod:`planner.studies.experiments_cloud`); each target, mapped to the world with the
   calibrated camera pose (its normal as the camera sees it, likewise), is planned with the
   product's :class:`planner.ik.BeamIK` on the calibrated system (points from home, path
   samples from the previous sample's joints);
4. open loop: the arm goes to the planned joints, the true beam lands on the true object
   and the camera measures the spot (mean of 5 frames); with servo lag
   (``Effects.servo_lag``) a path (curve, eyebrows) is swept at the scenario's spot speed
   and each sample is measured as the spot passes it, with the arm where the UR's servoJ
   follower has it then (:func:`swept_joints`);
5. closed loop: from there :func:`planner.servo.servo` corrects the spot in the calibrated
   model from the measured spots (the product's servo, default settings) and an
   independent final measurement (5 frames) is taken where it leaves the arm;
6. errors with the paper's metrics, in the camera frame as the camera measured both spot
   and target (point-to-point, or closest point to the measured path); and the same
   metrics without the camera (``true_*``: the true spot against the true target), which
   separates the calibration's error from the measurement noise; and how far the measured
   target and normal are from the true ones (``target_mm``, ``normal_deg``).

A row per target: ``status`` ok | hidden (target not seen) | unsolved | lost (spot not seen).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from planner.model.transforms import Array, inv_T, transform_points
from planner.studies import common
from planner.studies import experiments_setup as setup
from planner.studies.experiments_cell import FRAMES, Calibrated, Cell, calibrate_cell
from planner.studies.experiments_cloud import PICKED
from planner.studies.experiments_metrics import closest_point_error, point_error

ROBOT_STREAM = 1  # third entry of the seed of the true arm's kinematic error
CAMERA_STREAM = 2  # ... and of the true camera's disparity offset
EXPERIMENT_STREAM = 3  # ... and of the experiments' own draws (the finger's placement)


def _error(exp: setup.Experiment, k: int, spot_c: Array | None, seen_c: Array) -> float:
    """The paper's metric for target ``k`` (m; NaN when the spot was not seen)."""
    if spot_c is None:
        return float("nan")
    if exp.metric == setup.POINT:
        return point_error(spot_c, seen_c[k])
    stroke = next(s for s in exp.strokes if k in s)
    return closest_point_error(spot_c, seen_c[stroke])


def _true_error(exp: setup.Experiment, k: int, cell: Cell) -> float:
    """The same metric without the camera: the true spot (where the arm is now) against the
    true target or path (m; NaN without a spot)."""
    hit = cell.camera.true_spot_world()
    if hit is None:
        return float("nan")
    if exp.metric == setup.POINT:
        return point_error(hit[0], exp.points[k])
    stroke = next(s for s in exp.strokes if k in s)
    return closest_point_error(hit[0], exp.points[stroke])


class ClosedLoop:
    """The product's servo on the calibrated model, measuring through one :class:`Cell`."""

    def __init__(self, calibrated: Calibrated) -> None:
        from planner.servo import Corrector

        self.corrector = Corrector(calibrated.system)
        assert calibrated.system.camera is not None
        self.world_T_camera = calibrated.system.camera.world_T_camera

    def run(self, cell: Cell, q0: Array, target: Array, normal: Array) -> tuple[Array, Any]:
        """Servo from ``q0``; (joints where it left the arm, the servo's result)."""
        from planner.servo import SpotFrame, average_frames, servo

        def measure(q: Array, frames: int) -> Any:
            cell.move(q)
            got = [cell.camera.spot() for _ in range(frames)]
            seen = [SpotFrame(s.p_camera, s.confidence) for s in got if s is not None]
            return average_frames(seen, self.world_T_camera)

        res = servo(measure, q0, target, normal, self.corrector)
        return res.q, res


def measure_targets(exp: setup.Experiment, cell: Cell, cloud: bool = False) -> tuple[Array, Array]:
    """The targets as the true camera measures them (camera frame, m; NaN rows where not
    seen) and their normals in its frame: with ``cloud``, a picked experiment's
    (:data:`~planner.studies.experiments_cloud.PICKED`) are picked in the camera's cloud with
    SVD normals (:meth:`Cell.pick`); else the features are measured with the D435 corner
    noise (:meth:`Cell.see`) and carry the true normals."""
    if cloud and setup.group(exp.name) in PICKED:
        return cell.pick(exp.points)
    cam = cell.truth.camera
    assert cam is not None
    return cell.see(exp.points), exp.normals @ cam.world_T_camera[:3, :3]


def measurement_errors(exp: setup.Experiment, cell: Cell, seen_c: Array,
                       normals_c: Array) -> tuple[Array, Array]:  # fmt: skip
    """How far each measured target is from the true one (m) and its normal from the true
    normal (rad), in the true camera frame (NaN where not seen)."""
    cam = cell.truth.camera
    assert cam is not None
    R = cam.world_T_camera[:3, :3]
    true_c = transform_points(inv_T(cam.world_T_camera), exp.points)
    cos = np.clip(np.einsum("ij,ij->i", normals_c, exp.normals @ R), -1.0, 1.0)
    return np.linalg.norm(seen_c - true_c, axis=1), np.arccos(cos)


def planner_targets(seen_c: Array, normals_c: Array, cal: Calibrated) -> tuple[Array, Array]:
    """The targets as the planner knows them (world, through the calibrated camera pose):
    the measured points (K x 3, NaN rows where not seen) and normals (camera frame, K x 3)."""
    cam = cal.system.camera
    assert cam is not None
    T = cam.world_T_camera
    return transform_points(T, seen_c), normals_c @ T[:3, :3].T


def plan_targets(metric: str, targets: Array, normals: Array, home: Array, ik: Any) -> list[Any]:
    """The planned solution of every target (None where it was not seen): points from
    ``home``, path samples from the previous sample's joints."""
    q_prev = home
    out: list[Any] = []
    for k, (p, n) in enumerate(zip(targets, normals, strict=True)):
        if not np.all(np.isfinite(p)):
            out.append(None)
            continue
        sol = ik.solve(p, n, q_prev if metric == setup.CLOSEST and k else home)
        out.append(sol)
        if sol.q is not None:
            q_prev = sol.q
    return out


def swept_joints(exp: setup.Experiment, targets: Array, sols: list[Any], speed: float) -> list[Any]:
    """The joints of the arm when the spot passes each sample of ``exp``'s strokes swept at
    ``speed`` (m/s along the planned targets, from rest at each stroke's first sample; the
    command runs linearly through the planned joints) behind a UR's servoJ follower
    (:func:`drivers.robot.servo_lag.follow`, the driver's settings); the planned joints
    where there is no stroke; None where nothing was planned."""
    from drivers.robot.servo_lag import follow

    out = [None if s is None or s.q is None else s.q for s in sols]
    for stroke in exp.strokes:
        idx = [int(k) for k in stroke if out[k] is not None]
        if len(idx) < 2:
            continue
        step = np.linalg.norm(np.diff(targets[idx], axis=0), axis=1)
        t = np.concatenate([[0.0], np.cumsum(step)]) / speed + 1e-9 * np.arange(len(idx))
        for k, q in zip(idx, follow(t, np.array([out[k] for k in idx])), strict=True):
            out[k] = q
    return out


def run_experiment(exp: setup.Experiment, cal: Calibrated, truth: setup.Truth, ik: Any,
                   closed: ClosedLoop | None, seed: Any, lag: bool = False,
                   cloud: bool = False) -> list[dict[str, Any]]:  # fmt: skip
    """Rows (one per target) of one experiment run (see the module docstring; ``cloud``:
    :func:`measure_targets` picks the targets in the camera's cloud)."""
    cell = Cell(truth.system, exp.items, seed, truth.depth_errors)
    seen_c, normals_c = measure_targets(exp, cell, cloud)
    d_target, d_normal = measurement_errors(exp, cell, seen_c, normals_c)
    targets, normals = planner_targets(seen_c, normals_c, cal)
    sols = plan_targets(exp.metric, targets, normals, cal.system.home, ik)
    q_open = swept_joints(exp, targets, sols, setup.spot_speed()) if lag else None
    rows = []
    for k, sol in enumerate(sols):
        row: dict[str, Any] = {"experiment": exp.name, "group": setup.group(exp.name),
                               "target": k, "metric": exp.metric,
                               "target_mm": 1e3 * d_target[k],
                               "normal_deg": float(np.degrees(d_normal[k]))}  # fmt: skip
        status, e_open, e_closed, iters, t_ik = "hidden", np.nan, np.nan, 0, np.nan
        true_open, true_closed = np.nan, np.nan
        if sol is not None:
            status, t_ik = ("ok", sol.solve_time) if sol.q is not None else ("unsolved", np.nan)
        if status == "ok":
            spot = cell.spot(sol.q if q_open is None else q_open[k], FRAMES)
            e_open, true_open = _error(exp, k, spot, seen_c), _true_error(exp, k, cell)
            status = "ok" if spot is not None else "lost"
            if closed is not None and spot is not None:
                q_cl, res = closed.run(cell, sol.q, targets[k], normals[k])
                iters = res.iterations
                e_closed = _error(exp, k, cell.spot(q_cl, FRAMES), seen_c)
                true_closed = _true_error(exp, k, cell)
        row.update(status=status, open_mm=1e3 * e_open, closed_mm=1e3 * e_closed,
                   true_open_mm=1e3 * true_open, true_closed_mm=1e3 * true_closed,
                   servo_iterations=iters, ik_time_s=t_ik)  # fmt: skip
        rows.append(row)
    return rows


def run_trial(
    seed: int,
    trial: int,
    closed_loop: bool = True,
    unknowns: setup.Unknowns | None = None,
    effects: setup.Effects | None = None,
) -> dict[str, Any]:
    """One trial: its calibration figures and every target's row (``trial`` added). The
    true arm's kinematic error (``effects.robot``) and the true camera's disparity offset
    (``effects.depth_bias``) come from streams of their own (``[seed, trial, ROBOT_STREAM]``,
    ``[seed, trial, CAMERA_STREAM]``): the other draws stay those of the kind simulation.
    The experiments' own draws (``[seed, trial, EXPERIMENT_STREAM]``) do not depend on how
    many the calibration took, so the calibration designs
    (``effects.paper_calibration``) meet the same experiments."""
    from planner.ik import BeamIK
    from planner.plan.scenario_planner import ik_options

    effects = setup.Effects() if effects is None else effects
    rng = common.trial_rng(seed, trial)
    nominal = setup.nominal_system()
    u = setup.Unknowns() if unknowns is None else unknowns
    robot_rng = np.random.default_rng(np.random.SeedSequence([seed, trial, ROBOT_STREAM]))
    truth = setup.draw_truth(nominal, u, rng, effects.robot_spread, robot_rng)
    camera_rng = np.random.default_rng(np.random.SeedSequence([seed, trial, CAMERA_STREAM]))
    truth = replace(truth, depth_errors=effects.depth_errors(nominal, camera_rng))
    cal = calibrate_cell(nominal, truth, rng, effects.paper_calibration)
    ik = BeamIK(cal.system, ik_options(setup.solver_settings()))
    closed = ClosedLoop(cal) if closed_loop else None
    rows = []
    exp_rng = np.random.default_rng(np.random.SeedSequence([seed, trial, EXPERIMENT_STREAM]))
    for i, exp in enumerate(setup.experiments(exp_rng)):
        args = (exp, cal, truth, ik, closed, [seed, trial, i])
        for r in run_experiment(*args, effects.servo_lag, effects.cloud_targets):
            rows.append({"trial": trial, **r})
    return {
        "trial": trial,
        "handeye_residual_mm": 1e3 * float(np.mean(cal.handeye_residuals)),
        "beam_residual_mm": 1e3 * float(np.mean(cal.beam_residuals)),
        "beam_spots": cal.beam_spots,
        "rows": rows,
    }
