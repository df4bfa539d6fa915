"""The simulated counterparts of the paper's four real experiments, and the hidden truth.

Cell: ``scenarios/paper_n1.yaml`` (one UR5e with a 75 mm mirror, the laser low beside it,
a D435 0.85 m from the work). The nominal beam at home runs from the mirror down toward -y
at 40 deg from vertical and crosses z = 0 at ``CENTER``. World frame, metres.

Experiments (each an :class:`Experiment`: scene objects, target points with their outward
normals, and the metric):

- ``chessboard``: 7 x 5 inner corners, 25 mm, on a board at three placements
  (``A`` flat at z = -0.05, ``B`` at z = 0 tilted 20 deg toward the mirror, ``C`` flat at
  z = +0.05 shifted 30 mm along x); point-to-point error with correspondences.
- ``curve``: a sine curve (180 mm long, 35 mm amplitude, 60 samples) drawn on a board at
  z = -0.09; closest-point error (spot to the measured curve).
- ``face``: a procedural face phantom (:func:`face_height`, shipped as
  ``scenarios/face_phantom.ply``) resting at z = -0.06, with a trajectory along each
  eyebrow (2 x 20 samples on the surface); closest-point error.
- ``finger``: a cylinder (r = 9 mm, 80 mm long) lying at a random placement per trial
  (centre within +-30 mm, yaw U(-90, 90) deg) with 5 x 3 markers over +-40 deg of its top;
  point-to-point error.

The truth (:class:`Unknowns`): what a hand-assembled cell does not know before calibration
(uniform per component): the laser pose, the mirror on its mount, the camera pose and the
calibration board on the flange; optionally the arm's own kinematic error
(:mod:`planner.model.kinematic_error`: the true UR5e's DH deltas, while the planner keeps
the nominal model).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.data import scenarios_dir, shipped_scenario
from planner.model import d435
from planner.model.scene import SceneItem
from planner.model.system import System
from planner.model.transforms import Array, make_T, rpy_to_matrix

if TYPE_CHECKING:  # the kinematics (Pinocchio) load when a trial runs, not at --help
    from planner.model.kinematic_error import KinematicSpread

SCENARIO = shipped_scenario("paper_n1.yaml")
FACE_PLY = "face_phantom.ply"
CENTER = np.array([-0.492, -0.519, 0.0])
BEAM_DIR = np.array([0.0, -np.sin(np.radians(40.0)), -np.cos(np.radians(40.0))])
"""Nominal beam direction from the mirror at home (down toward -y)."""
POINT, CLOSEST = "point-to-point", "closest point"


@dataclass(frozen=True)
class Unknowns:
    """Half-widths of the uniform errors of the truth about the nominal geometry, per
    component (rad about each axis, m along each axis)."""

    laser_rot: float = np.radians(0.5)
    laser_pos: float = 0.005
    mirror_rot: float = np.radians(0.5)
    mirror_pos: float = 0.003
    camera_rot: float = np.radians(2.0)
    camera_pos: float = 0.03
    board_rot: float = np.radians(1.0)
    board_pos: float = 0.002

    def describe(self) -> str:
        """One line: the levels in mm / deg."""
        f = [("laser", self.laser_pos, self.laser_rot), ("mirror mount", self.mirror_pos,
             self.mirror_rot), ("camera", self.camera_pos, self.camera_rot),
             ("board on the flange", self.board_pos, self.board_rot)]  # fmt: skip
        return ", ".join(f"{n} ±{1e3 * p:g} mm / ±{np.degrees(r):g} deg" for n, p, r in f)


NONE = Unknowns(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
"""No unknowns: the truth is the nominal geometry."""


@dataclass(frozen=True)
class Effects:
    """The imperfections of a real cell the simulation adds (default: none of them, the
    kind simulation): ``camera_noise`` the D435's depth pixels correlated over its census
    window (with the detectors' real window statistics), ``depth_bias`` the camera's own
    disparity offset (uniform within the datasheet's bound, :mod:`planner.model.d435`),
    ``robot`` the true arm's kinematic error level
    (:data:`planner.model.kinematic_error.LEVELS`: none, factory, uncalibrated) and
    ``servo_lag`` the arm following servoJ as a UR does while it sweeps a path
    (:mod:`drivers.robot.servo_lag`). ``paper_calibration`` is not an imperfection but a
    design: the paper's calibration (hand-eye from random poses, the laser spot servoed onto
    known fiducials) instead of ours (well-conditioned poses, the spot measured in 3D),
    :func:`planner.studies.experiments_cell.calibrate_cell`."""

    camera_noise: bool = False
    depth_bias: bool = False
    robot: str = "none"
    servo_lag: bool = False
    cloud_targets: bool = False
    """The curve, face and finger targets picked in the camera's point cloud with SVD normals,
    as the paper did (:mod:`planner.studies.experiments_cloud`; the chessboard is detected)."""
    paper_calibration: bool = False

    @property
    def robot_spread(self) -> KinematicSpread | None:
        from planner.model.kinematic_error import LEVELS

        return LEVELS[self.robot]

    def depth_errors(self, nominal: System, rng: np.random.Generator) -> d435.DepthErrors | None:
        """The true camera's depth errors (None: the kind model); its offset from ``rng``."""
        if not (self.camera_noise or self.depth_bias):
            return None
        assert nominal.camera is not None
        fx = nominal.camera.intrinsics.fx
        offset = d435.DepthErrors.draw_offset(rng, fx) if self.depth_bias else 0.0
        return d435.DepthErrors(self.camera_noise, offset)

    def describe(self) -> str:
        """One line: the effects that are on."""
        on = [name for name, flag in (("camera noise (correlated)", self.camera_noise),
                                      ("depth bias", self.depth_bias)) if flag]  # fmt: skip
        on += ["targets from the cloud (SVD normals)"] if self.cloud_targets else []
        on += [f"robot kinematics {self.robot}"] if self.robot != "none" else []
        on += ["servo lag"] if self.servo_lag else []
        on += ["the paper's calibration design"] if self.paper_calibration else []
        return ", ".join(on) or "none"


@dataclass(frozen=True)
class Truth:
    """The hidden geometry of one trial: the true system, the true board mount and the
    true camera's depth errors (None: the kind model)."""

    system: System
    flange_T_board: Array
    depth_errors: d435.DepthErrors | None = None


@dataclass(frozen=True)
class Experiment:
    """One experiment: scene objects, target points (K x 3, world) with unit outward
    normals, the polyline pieces (``strokes``: index arrays into ``points``; a path
    metric measures each spot against its own stroke) and the metric."""

    name: str
    items: tuple[SceneItem, ...]
    points: Array
    normals: Array
    metric: str
    strokes: tuple[Any, ...] = ()


@lru_cache(maxsize=1)
def nominal_system() -> System:
    """The planner's nominal system (``scenarios/paper_n1.yaml``)."""
    from planner.io.scenario import load_scenario, system_from_scenario

    return system_from_scenario(load_scenario(SCENARIO))


def solver_settings() -> Any:
    """The scenario's ``solver`` section (tolerance, incidence limit)."""
    from planner.io.scenario import load_scenario

    return load_scenario(SCENARIO).model.solver


def spot_speed() -> float:
    """The scenario's spot speed along a path, m/s (``trajectory.spot_speed``)."""
    from planner.io.scenario import load_scenario

    return float(load_scenario(SCENARIO).model.trajectory.spot_speed)


NOMINAL_BOARD = make_T(p=[0.0, 0.0, 0.01])
"""Nominal ``flange_T_board`` of the hand-eye board (10 mm off the flange, facing out)."""


def perturb(T: Array, rng: np.random.Generator, rot: float, pos: float) -> Array:
    """``T`` times a random rigid error: U(-rot, rot) rpy, U(-pos, pos) per axis."""
    return T @ make_T(rpy_to_matrix(rng.uniform(-rot, rot, 3)), rng.uniform(-pos, pos, 3))


def draw_truth(
    nominal: System,
    u: Unknowns,
    rng: np.random.Generator,
    robot: KinematicSpread | None = None,
    robot_rng: np.random.Generator | None = None,
) -> Truth:
    """A random true geometry about ``nominal`` at the levels ``u``; with ``robot``, the
    true arm also has DH deltas drawn at that spread from ``robot_rng`` (a stream of its
    own, so the other draws do not change with it)."""
    r = nominal.robots[0]
    assert nominal.camera is not None
    laser = perturb(nominal.world_T_laser, rng, u.laser_rot, u.laser_pos)
    mount = perturb(r.mirror.flange_T_mirror, rng, u.mirror_rot, u.mirror_pos)
    cam = perturb(nominal.camera.world_T_camera, rng, u.camera_rot, u.camera_pos)
    board = perturb(NOMINAL_BOARD, rng, u.board_rot, u.board_pos)
    true = nominal.with_params(world_T_laser=laser, flange_T_mirror={r.name: mount})
    if robot is not None:
        from planner.model.kinematic_error import true_robot

        arm = true_robot(r, robot, rng if robot_rng is None else robot_rng)
        true = replace(true, robots=(arm, *true.robots[1:]))
    return Truth(replace(true, camera=replace(nominal.camera, world_T_camera=cam)), board)


# --- objects ------------------------------------------------------------------------------
def _at(dx: float, dy: float, dz: float) -> Array:
    """``CENTER`` offset by (dx, dy, dz) m."""
    return CENTER + np.array([dx, dy, dz])


def board_box(name: str, world_T_top: Array, size: tuple[float, float] = (0.3, 0.3)) -> SceneItem:
    """A 10 mm board whose top face is the xy plane of ``world_T_top``."""
    T = world_T_top @ make_T(p=[0.0, 0.0, -0.005])
    return SceneItem(name, "box", T, extents=np.array([*size, 0.01]))


def on_plane(T: Array, uv: Array) -> tuple[Array, Array]:
    """Points (u, v, 0) of plane frame ``T`` in the world, and its normal for each."""
    pts = uv @ T[:3, :2].T + T[:3, 3]
    return pts, np.tile(T[:3, 2], (len(pts), 1))


CHESSBOARD = {
    "A": make_T(p=_at(0.0, 0.0, -0.05)),
    "B": make_T(rpy_to_matrix([np.radians(-20.0), 0.0, 0.0]), CENTER),
    "C": make_T(p=_at(0.03, 0.0, 0.05)),
}
"""``world_T_board`` (top face) of the three chessboard placements."""
CURVE_BOARD = make_T(p=_at(0.0, 0.0, -0.09))
FACE_BASE = make_T(p=_at(0.0, 0.0, -0.06))
CALIBRATION_BOARDS = (-0.10, 0.0, 0.10)
"""z (m) of the three boards the beam calibration's spots land on."""


def beam_point(z: float) -> Array:
    """Where the nominal beam at home crosses the height ``z`` (m)."""
    return CENTER + BEAM_DIR * (z / BEAM_DIR[2])


def calibration_board(z: float) -> SceneItem:
    """A 0.4 m square board, flat, top at height ``z``, centred on the nominal beam."""
    return board_box(f"board_z{z:+.2f}", make_T(p=beam_point(z)), (0.4, 0.4))


def chessboard(placement: str) -> Experiment:
    """7 x 5 corners (25 mm) on the board at ``placement`` (A, B or C)."""
    T = CHESSBOARD[placement]
    gx, gy = np.meshgrid(np.arange(-3, 4) * 0.025, np.arange(-2, 3) * 0.025)
    pts, n = on_plane(T, np.column_stack([gx.ravel(), gy.ravel()]))
    return Experiment(f"chessboard {placement}", (board_box("chessboard", T),), pts, n, POINT)


def curve() -> Experiment:
    """60 samples of a sine curve drawn on a board at z = -0.09."""
    s = np.linspace(-0.09, 0.09, 60)
    pts, n = on_plane(CURVE_BOARD, np.column_stack([s, 0.035 * np.sin(2 * np.pi * s / 0.09)]))
    strokes = (np.arange(len(s)),)
    return Experiment("curve", (board_box("curve_board", CURVE_BOARD),), pts, n, CLOSEST, strokes)


def face_height(x: Array, y: Array) -> Array:
    """Face-like height field (m) over a 0.14 x 0.18 m oval: dome, nose, brows, cheeks
    (x across the face, y toward the forehead; object frame of the phantom)."""

    def g(x0: float, y0: float, s: float, h: float) -> Array:
        return h * np.exp(-((x - x0) ** 2 + (y - y0) ** 2) / (2 * s**2))

    dome = 0.035 * np.clip(1 - (x / 0.07) ** 2 - (y / 0.09) ** 2, 0, None)
    brows = g(-0.03, 0.035, 0.012, 0.006) + g(0.03, 0.035, 0.012, 0.006)
    cheeks = g(-0.035, -0.015, 0.015, 0.006) + g(0.035, -0.015, 0.015, 0.006)
    return dome + g(0, 0.0, 0.01, 0.02) + brows + cheeks


def face_mesh(step: float = 0.003) -> tuple[Array, Array]:
    """The phantom's triangle mesh (object frame): vertices (V x 3, m), triangles (T x 3)."""
    xs, ys = np.arange(-0.072, 0.0721, step), np.arange(-0.093, 0.0931, step)
    X, Y = np.meshgrid(xs, ys)
    verts = np.column_stack([X.ravel(), Y.ravel(), face_height(X, Y).ravel()])
    nx = len(xs)
    i = (np.arange(len(ys) - 1)[:, None] * nx + np.arange(nx - 1)[None]).ravel()
    tris = np.vstack(
        [np.column_stack([i, i + 1, i + nx]), np.column_stack([i + 1, i + nx + 1, i + nx])]
    )
    return verts, tris


def write_face_ply(path: Path) -> None:
    """Write :func:`face_mesh` as a binary PLY (the shipped ``scenarios/face_phantom.ply``)."""
    import open3d as o3d

    v, t = face_mesh()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=False)  # type: ignore[arg-type]


def _face_normals(x: Array, y: Array) -> Array:
    e = 1e-5
    dzx = (face_height(x + e, y) - face_height(x - e, y)) / (2 * e)
    dzy = (face_height(x, y + e) - face_height(x, y - e)) / (2 * e)
    n = np.column_stack([-dzx, -dzy, np.ones_like(x)])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def face() -> Experiment:
    """The phantom with a 20-sample trajectory along each eyebrow (an arc over the brow)."""
    s = np.linspace(-1.0, 1.0, 20)
    x, y = [], []
    for side in (-1.0, 1.0):
        x.append(side * (0.03 + 0.018 * s))
        y.append(0.038 - 0.008 * s**2)
    X, Y = np.concatenate(x), np.concatenate(y)
    R, p = FACE_BASE[:3, :3], FACE_BASE[:3, 3]
    pts = np.column_stack([X, Y, face_height(X, Y)]) @ R.T + p
    n = _face_normals(X, Y) @ R.T
    item = SceneItem("face", "mesh", FACE_BASE, mesh_path=scenarios_dir() / FACE_PLY)
    strokes = (np.arange(20), np.arange(20, 40))
    return Experiment("face", (item,), pts, n, CLOSEST, strokes)


FINGER_R, FINGER_LEN = 0.009, 0.08


def finger(rng: np.random.Generator) -> Experiment:
    """The cylinder at a random placement, lying on a board at z = -0.04, 15 markers."""
    yaw = rng.uniform(-np.pi / 2, np.pi / 2)
    dx, dy = rng.uniform(-0.03, 0.03, 2)
    c = _at(dx, dy, -0.04 + FINGER_R)
    axis_T = make_T(rpy_to_matrix([0.0, 0.0, yaw]), c)  # x = the finger's axis
    cyl_T = axis_T @ make_T(rpy_to_matrix([0.0, np.pi / 2, 0.0]))  # cylinder z along x
    along, ang = np.meshgrid(np.linspace(-0.03, 0.03, 5), np.radians([-40.0, 0.0, 40.0]))
    n_local = np.column_stack([0 * ang.ravel(), np.sin(ang.ravel()), np.cos(ang.ravel())])
    p_local = np.column_stack([along.ravel(), 0 * along.ravel(), 0 * along.ravel()])
    pts = (p_local + FINGER_R * n_local) @ axis_T[:3, :3].T + c
    n = n_local @ axis_T[:3, :3].T
    cyl = SceneItem("finger", "cylinder", cyl_T, radius=FINGER_R, height=FINGER_LEN)
    table = board_box("table", make_T(p=_at(0.0, 0.0, -0.04)))
    return Experiment("finger", (cyl, table), pts, n, POINT)


def experiments(rng: np.random.Generator) -> list[Experiment]:
    """The six experiment runs of one trial (three chessboard placements)."""
    return [*(chessboard(p) for p in CHESSBOARD), curve(), face(), finger(rng)]


GROUPS = ("chessboard", "curve", "face", "finger")
"""The paper's four experiments (the chessboard pools its three placements)."""


def group(name: str) -> str:
    """The paper experiment an experiment run belongs to (``chessboard B`` -> chessboard)."""
    return name.split(" ")[0]
