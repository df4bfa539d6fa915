"""The simulated cell of the experiments, in process: the sim camera driver's own classes on
the hidden truth, the product's calibration collection and calibration code.

- :class:`Cell`: one scene (the objects of one experiment, or one calibration board) seen
  by :class:`drivers.camera.sim.SimCamera` built on the TRUE system (and the true camera's
  depth errors, when the trial has them): ``spot(q)`` puts the
  robot at ``q`` (joint states), traces the true beam onto the true objects and returns the
  camera's detected spot (D435 spot noise), averaged over ``frames`` frames; ``see(points)``
  measures target features (D435 corner noise) where the true camera sees them;
  ``pick(points)`` picks them in one frame of its full-resolution cloud with SVD normals
  (:mod:`planner.studies.experiments_cloud`).
- :func:`calibrate_cell`: the calibration, in one of two designs. Ours (default):
  hand-eye from 20 well-conditioned poses planned on the nominal geometry
  (:func:`planner.calibration.collect.handeye_plan`: the best-conditioned 20 of 60 random
  candidates), the board corners measured by the sim camera (``SimCamera.markers``) at the
  true poses, :func:`planner.calibration.handeye.calibrate_handeye`; beam: 16 poses per
  board at the three :data:`CALIBRATION_BOARDS` placements
  (:func:`planner.calibration.collect.beam_plan`), each spot measured in 3D by the camera
  and mapped to the world with the calibrated camera pose,
  :func:`planner.calibration.beam.calibrate_beam`. The paper's (``paper=True``): hand-eye
  from 20 random poses (:func:`planner.calibration.collect.random_handeye_plan`, no
  selection); beam: the spot servoed onto 16 known fiducials per board and the (joints,
  fiducial) pairs calibrated (:mod:`planner.studies.experiments_fiducials`). The result is
  the planner's calibrated system (camera, laser, mirror mount).
Units: metres, radians; camera = OpenCV optical frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.model import d435
from planner.model.scene import SceneItem
from planner.model.system import System
from planner.model.transforms import Array, inv_T, transform_points
from planner.studies.experiments_cloud import CloudTargets, pick_targets
from planner.studies.experiments_setup import (
    CALIBRATION_BOARDS,
    NOMINAL_BOARD,
    Truth,
    beam_point,
    calibration_board,
)

ROBOT = "arm0"
FRAMES = 5  # camera frames averaged per measured spot
HANDEYE_POSES = 20
BEAM_POSES = 16  # per board placement


class Cell:
    """The true system with one scene, seen by the simulated D435 (see module docstring)."""

    def __init__(self, truth: System, items: tuple[SceneItem, ...], seed: Any,
                 errors: d435.DepthErrors | None = None) -> None:  # fmt: skip
        from drivers.camera.sim import SimCamera

        self.truth = truth
        self.items = items
        self.errors = errors  # the true camera's own depth errors (None: the kind model)
        self.camera = SimCamera(truth, list(items), stride=64, seed=seed, depth_errors=errors)
        self.rng = np.random.default_rng(seed)

    def move(self, q: Array) -> None:
        """Put the robots at stacked joints ``q`` (rad, beam order; the first robots' only
        when shorter, e.g. one arm of the chain)."""
        start = 0
        for r in self.truth.robots:
            if start + r.nq > len(q):
                break
            self.camera.on_joint_state(r.name, np.asarray(q[start : start + r.nq]))
            start += r.nq

    def spot(self, q: Array, frames: int = FRAMES) -> Array | None:
        """The measured spot (camera frame, m) with the arms at stacked joints ``q``: the
        mean of the ``frames`` detections, None when the camera sees no spot."""
        self.move(q)
        got = [s.p_camera for s in (self.camera.spot() for _ in range(frames)) if s is not None]
        return np.mean(got, axis=0) if got else None

    def visible(self, points_world: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Points (K x 3, world, m) in the true camera frame, and whether the true camera
        sees each (nothing in front, in front of the camera, inside the image)."""
        cam = self.truth.camera
        assert cam is not None
        k, c = cam.intrinsics, cam.world_T_camera[:3, 3]
        to = np.asarray(points_world, dtype=float) - c
        dist = np.linalg.norm(to, axis=1)
        hit = _cast(self.camera.scene, c, to / dist[:, None])
        p = transform_points(inv_T(cam.world_T_camera), points_world)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = k.fx * p[:, 0] / p[:, 2] + k.cx, k.fy * p[:, 1] / p[:, 2] + k.cy
        ok = (hit >= dist - 1e-4) & (p[:, 2] > 0.1) & (u >= 0) & (u < k.width)
        ok &= (v >= 0) & (v < k.height)
        return p, ok

    def see(self, points_world: Array, noise: d435.D435Noise | None = None) -> Array:
        """Measured features (K x 3, camera frame, m; NaN where hidden or off the image);
        ``noise`` defaults to the D435 corner model :data:`planner.model.d435.CORNER`."""
        p, ok = self.visible(points_world)
        k = self.camera.camera.intrinsics
        out = (noise or d435.CORNER).with_focal(k.fx).with_errors(self.errors).apply(p, self.rng)
        out[~ok] = np.nan
        return out

    def pick(self, points_world: Array) -> CloudTargets:
        """Targets (K x 3, world, m) picked in one frame of the true camera's full-resolution
        cloud with their SVD normals (:mod:`planner.studies.experiments_cloud`; camera frame,
        NaN where hidden); the cloud's noise from a stream of its own."""
        from drivers.camera.sim import SimCamera

        p, ok = self.visible(points_world)
        seed = int(self.rng.integers(2**63))
        cam = SimCamera(self.truth, list(self.items), seed=seed, depth_errors=self.errors)
        cloud, meta = cam.points()
        z, rays = cam.depth()  # the same pixels without noise: what the colour image shows
        clean = np.asarray(rays, dtype=float) * np.asarray(z, dtype=float)[:, None]
        k, stride = cam.camera.intrinsics, int(meta["stride"])
        return pick_targets(np.asarray(cloud, dtype=float), clean, p, ok, k, stride)


def _cast(scene: Any, origin: Array, dirs: Array) -> Array:
    """Distance (m, inf = miss) along unit rays from ``origin`` to an open3d scene."""
    import open3d as o3d

    rays = np.hstack([np.broadcast_to(origin, dirs.shape), dirs]).astype(np.float32)
    return np.asarray(scene.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy(), float)


@dataclass(frozen=True)
class Calibrated:
    """The planner's calibrated system and the calibration's residuals (m)."""

    system: System
    handeye_residuals: Array
    beam_residuals: Array
    beam_spots: int


def calibrate_handeye_cell(
    nominal: System,
    truth: Truth,
    rng: np.random.Generator,
    robot: str = ROBOT,
    paper: bool = False,
) -> Any:
    """Hand-eye data collected on the simulated cell with the board on ``robot``'s flange
    and calibrated (eye to hand: the camera pose in the world through ``robot``'s nominal
    base); poses well-conditioned (ours) or random (``paper``)."""
    from drivers.camera.sim import SimCamera
    from planner.calibration.collect import handeye_plan, random_handeye_plan
    from planner.calibration.handeye import HandEyeData, calibrate_handeye
    from planner.calibration.simulate import board_grid

    board = board_grid()
    plan = random_handeye_plan if paper else handeye_plan
    qs, _ = plan(nominal, robot, "eye_to_hand", HANDEYE_POSES, board, NOMINAL_BOARD, rng)
    cam = SimCamera(truth.system, [], stride=64, seed=int(rng.integers(2**31)),
                    depth_errors=truth.depth_errors)  # fmt: skip
    request = {"board_points": board.tolist(), "board_pose": truth.flange_T_board.tolist(),
               "robot": robot}  # fmt: skip
    pts = []
    for q in qs:
        cam.on_joint_state(robot, q)
        pts.append(cam.markers(request))
    data = HandEyeData(robot, "eye_to_hand", board, qs, np.array(pts))
    return calibrate_handeye(data, nominal)


def board_cells(truth: Truth, rng: np.random.Generator) -> list[Cell]:
    """One cell per :data:`CALIBRATION_BOARDS` placement, the board alone on the truth."""
    return [Cell(truth.system, (calibration_board(z),), int(rng.integers(2**31)),
                 truth.depth_errors) for z in CALIBRATION_BOARDS]  # fmt: skip


#: a beam calibration board: where the planned poses aim (world, m) and the board itself
Board = tuple[Array, SceneItem]


def default_boards() -> list[Board]:
    """The N = 1 boards: flat, at the heights :data:`CALIBRATION_BOARDS`, on the beam."""
    return [(beam_point(z), calibration_board(z)) for z in CALIBRATION_BOARDS]


def collect_beam_cell(plan_system: System, truth: Truth, world_T_camera: Array,
                      rng: np.random.Generator, robot: str = ROBOT,
                      boards: list[Board] | None = None,
                      scene: tuple[SceneItem, ...] = ()) -> Any:  # fmt: skip
    """Beam data for ``robot``'s mirror: :data:`BEAM_POSES` poses per board planned on
    ``plan_system`` (:func:`planner.calibration.collect.beam_plan`), each spot measured by
    the camera on the true chain up to ``robot`` (the robots after it out of the beam) and
    mapped to the world with ``world_T_camera``; a :class:`~planner.calibration.beam.BeamData`.
    ``scene``: objects in the cell beside each board (a spot on one of them is a point of
    the ray as good as one on the board, and it may hide the board)."""
    from planner.calibration.beam import BeamData
    from planner.calibration.collect import beam_plan

    k = truth.system.robot_names.index(robot) + 1
    true_chain = replace(truth.system, robots=truth.system.robots[:k])
    qs, spots, labels = [], [], []
    for b, (aim, item) in enumerate(default_boards() if boards is None else boards):
        plan, _ = beam_plan(plan_system, robot, BEAM_POSES, aim, rng)
        cell = Cell(true_chain, (item, *scene), int(rng.integers(2**31)), truth.depth_errors)
        for q in plan:
            s = cell.spot(q)
            if s is not None:
                qs.append(q)
                spots.append(transform_points(world_T_camera, s[None])[0])
                labels.append(b)
    return BeamData(robot, np.array(qs), np.array(spots), np.array(labels), len(spots))


def beam_cell_data(
    nominal: System, truth: Truth, world_T_camera: Array, rng: np.random.Generator, paper: bool
) -> Any:
    """Beam data (16 poses x 3 boards) collected on the simulated cell: 3D spots measured by
    the camera (ours, :func:`collect_beam_cell`) or (joints, fiducial) pairs (``paper``)."""
    if paper:
        from planner.studies.experiments_fiducials import fiducial_beam_data, fiducial_runs

        runs = fiducial_runs(nominal, world_T_camera, board_cells(truth, rng))
        return fiducial_beam_data(ROBOT, runs)
    return collect_beam_cell(nominal, truth, world_T_camera, rng)


def calibrate_beam_cell(nominal: System, truth: Truth, world_T_camera: Array,
                        rng: np.random.Generator, paper: bool = False) -> Any:  # fmt: skip
    """Beam data collected on the simulated cell (:func:`beam_cell_data`) and calibrated."""
    from planner.calibration.beam import calibrate_beam

    return calibrate_beam(beam_cell_data(nominal, truth, world_T_camera, rng, paper), nominal)


def calibrate_cell(
    nominal: System, truth: Truth, rng: np.random.Generator, paper: bool = False
) -> Calibrated:
    """The calibration on the simulated cell, ours or the paper's design (``paper``):
    hand-eye, then laser + mirror (see the module docstring)."""
    assert nominal.camera is not None
    he = calibrate_handeye_cell(nominal, truth, rng, paper=paper)
    bm = calibrate_beam_cell(nominal, truth, he.camera_pose, rng, paper)
    system = nominal.with_params(
        world_T_laser=bm.world_T_laser, flange_T_mirror={ROBOT: bm.flange_T_mirror}
    )
    system = replace(system, camera=replace(nominal.camera, world_T_camera=he.camera_pose))
    return Calibrated(system, he.point_residuals, bm.residuals, len(bm.residuals))
