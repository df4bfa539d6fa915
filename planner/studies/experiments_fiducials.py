"""The paper's beam-calibration design on the simulated cell: the spot driven onto fiducials.

Instead of measuring the laser spot in 3D with the camera, the paper drove the spot onto
fiducials at known places and recorded the robot's joints. Here, per calibration board
(:data:`~planner.studies.experiments_setup.CALIBRATION_BOARDS`):

1. the board carries :data:`GRID` fiducials (4 x 4 = the paper's 16 poses per board) on its
   top face, a known pattern; the camera measures them (D435 corner noise,
   :meth:`~planner.studies.experiments_cell.Cell.see`), they are mapped to the world with the
   hand-eye-calibrated camera pose and the pattern is fitted to them (rigid, Kabsch):
   the fitted pattern is each fiducial's known position (world, m), and the fit's z axis
   the board's normal;
2. for each fiducial the product's IK (:class:`planner.ik.BeamIK`, nominal laser and mirror)
   aims the spot at it, then the product's servo (:func:`planner.servo.servo`, its default
   settings: 0.3 mm with confidence) drives the spot onto it as the camera sees both (the
   measured spot and the fiducial are mapped with the same camera pose, so its error
   cancels in their difference);
3. each run gives one pair (joints where the servo left the arm, fiducial position): when it
   converged, and also when it stopped as not improving or at its iteration limit - the
   camera's noise then decides (correlated depth pixels put single measurements ~0.5 mm
   apart, beyond the servo's 0.3 mm with confidence) and the arm is left at the best
   measured joints (or the last, within the noise), where an operator would record them;
   a run whose spot was not seen or whose step was refused gives none. The pairs are a
   :class:`planner.calibration.beam.BeamData` whose spots are the fiducial positions: the
   same residual (the fiducial's distance from the model's last ray) and solver as the
   3D-spot design.

Units: metres, radians; world frame unless stated.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from planner.calibration.simulate import BOARD_HALF
from planner.model.system import System
from planner.model.transforms import Array, transform_points
from planner.studies.experiments_setup import CALIBRATION_BOARDS, beam_point

# 4 x 4 fiducials (the paper's 16 poses per board, SPEC section 8) spanning the region the
# 3D-spot design's spots land in (+-BOARD_HALF, planner.calibration.simulate), so both
# designs sample the same part of the board; board frame (x, y along the world's), m
_SIDE = np.linspace(-BOARD_HALF, BOARD_HALF, 4)
GRID = np.array([[x, y, 0.0] for y in _SIDE for x in _SIDE])


class FiducialRuns(NamedTuple):
    """Per board: the fiducials' true and located positions (K x 3), the servo's final
    joints (K x nq, NaN rows where it gave no pair), its final measured error (m, NaN
    likewise) and whether it converged (K,)."""

    true_world: Array
    located_world: Array
    q: Array
    error: Array
    converged: Array


def board_fiducials(z: float) -> Array:
    """The true fiducials (16 x 3, world) on the calibration board whose top is at ``z``."""
    return GRID + beam_point(z)


def locate(seen_camera: Array, world_T_camera: Array) -> tuple[Array, Array]:
    """The fiducials' known positions (16 x 3, world) and the board normal: :data:`GRID`
    fitted (rigid) to the measured fiducials (camera frame, NaN rows = not seen) mapped to
    the world with ``world_T_camera``."""
    from planner.calibration.handeye import fit_rigid
    from planner.errors import CalibrationError

    ok = np.all(np.isfinite(seen_camera), axis=1)
    if ok.sum() < 3:
        raise CalibrationError(f"the camera sees {int(ok.sum())} fiducials, needs 3", [])
    world = transform_points(world_T_camera, seen_camera[ok])
    T = fit_rigid(GRID[ok], world)
    return transform_points(T, GRID), T[:3, 2]


def drive_to_fiducials(cell: Any, model: System, world_T_camera: Array, fiducials: Array,
                       normal: Array, ik: Any) -> tuple[Array, Array, Array]:  # fmt: skip
    """Servo the spot onto each fiducial (world, m) in ``model`` (the planner's system),
    measuring through ``cell``'s camera; (final joints, K x nq, NaN where the run gives no
    pair (module docstring, 3.); final measured error, m, NaN likewise; converged, K)."""
    from planner.servo import Corrector, ServoStatus, SpotFrame, average_frames, servo

    recorded = (ServoStatus.CONVERGED, ServoStatus.NOT_IMPROVING, ServoStatus.MAX_ITERATIONS)

    corrector = Corrector(model)

    def measure(q: Array, frames: int) -> Any:
        cell.camera.on_joint_state("arm0", q)
        got = [cell.camera.spot() for _ in range(frames)]
        seen = [SpotFrame(s.p_camera, s.confidence) for s in got if s is not None]
        return average_frames(seen, world_T_camera)

    qs = np.full((len(fiducials), model.nq), np.nan)
    err = np.full(len(fiducials), np.nan)
    converged = np.zeros(len(fiducials), dtype=bool)
    for k, f in enumerate(fiducials):
        sol = ik.solve(f, normal, model.home)
        if sol.q is None:
            continue
        res = servo(measure, sol.q, f, normal, corrector)
        converged[k] = res.converged
        if res.status in recorded and np.isfinite(res.error_after):
            qs[k], err[k] = res.q, res.error_after
    return qs, err, converged


def fiducial_runs(
    nominal: System, world_T_camera: Array, cells: Sequence[Any]
) -> list[FiducialRuns]:
    """The spot driven onto every fiducial of the calibration boards (see the module
    docstring), the planner on ``nominal`` with the calibrated camera pose; ``cells``: one
    :class:`~planner.studies.experiments_cell.Cell` per board of
    :data:`~planner.studies.experiments_setup.CALIBRATION_BOARDS`, in order."""
    from dataclasses import replace

    from planner.ik import BeamIK
    from planner.plan.scenario_planner import ik_options
    from planner.studies.experiments_setup import solver_settings

    assert nominal.camera is not None
    model = replace(nominal, camera=replace(nominal.camera, world_T_camera=world_T_camera))
    ik = BeamIK(model, ik_options(solver_settings()))
    out = []
    for z, cell in zip(CALIBRATION_BOARDS, cells, strict=True):
        true = board_fiducials(z)
        located, normal = locate(cell.see(true), world_T_camera)
        qs, err, conv = drive_to_fiducials(cell, model, world_T_camera, located, normal, ik)
        out.append(FiducialRuns(true, located, qs, err, conv))
    return out


def fiducial_beam_data(robot: str, runs: list[FiducialRuns]) -> Any:
    """The converged (joints, fiducial position) pairs as beam-calibration data, labelled by
    board."""
    from planner.calibration.beam import BeamData

    qs, spots, labels = [], [], []
    for b, run in enumerate(runs):
        ok = np.all(np.isfinite(run.q), axis=1)
        qs.append(run.q[ok])
        spots.append(run.located_world[ok])
        labels += [b] * int(ok.sum())
    return BeamData(robot, np.vstack(qs), np.vstack(spots), np.array(labels))
