"""Synthetic calibration datasets from a (true) system, with a D435 depth-noise model.

Robot poses are physically valid: hand-eye poses are chosen as board poses inside the
camera's view and reached by analytic IK (solution nearest home, within limits); beam
poses are small joint perturbations around a configuration that aims every mirror of the
chain, kept only when each reflection is valid (ahead, front face, inside the ROI) and the
spot lands on the board placement. Units: metres, radians; camera = OpenCV optical frame.
"""

from __future__ import annotations

import numpy as np

from planner.beam.graph import BeamModel
from planner.calibration.beam import BeamData, _min_rotation
from planner.calibration.handeye import HandEyeData
from planner.errors import InputError
from planner.model.d435 import D435Noise
from planner.model.system import Robot, System
from planner.model.transforms import Array, axis_angle_to_matrix, inv_T, make_T, transform_points

PERTURB_SIGMA = np.array([0.02, 0.02, 0.02, 0.06, 0.06, 0.06])  # rad, around the aimed pose
BOARD_HALF = 0.15  # m, half side of a square spot board


DepthNoise = D435Noise
"""The D435 noise model (:mod:`planner.model.d435`); default: one raw depth pixel, the
ChArUco corner's lateral noise (``d435.CORNER_PX``)."""


def board_grid(nx: int = 7, ny: int = 5, spacing: float = 0.03) -> Array:
    """Marker points (m) of a flat board in its own frame, centred, z = 0."""
    xs = (np.arange(nx) - (nx - 1) / 2) * spacing
    ys = (np.arange(ny) - (ny - 1) / 2) * spacing
    return np.array([[x, y, 0.0] for y in ys for x in xs])


def ik_near(robot: Robot, world_T_flange: Array, q_ref: Array) -> Array | None:
    """Analytic IK solution within limits nearest ``q_ref`` (None if unreachable)."""
    base_T_flange = inv_T(robot.world_T_base) @ world_T_flange
    best, best_d = None, np.inf
    for q in robot.kinematics.analytic_ik(base_T_flange):
        q = q_ref + (q - q_ref + np.pi) % (2 * np.pi) - np.pi  # nearest 2pi-equivalent
        if np.any(q < robot.limits.lower) or np.any(q > robot.limits.upper):
            continue
        d = float(np.linalg.norm(q - q_ref))
        if d < best_d:
            best, best_d = q, d
    return best


def _random_rotation_about(axis_cone: Array, max_tilt: float, rng: np.random.Generator) -> Array:
    """A rotation whose z axis lies within ``max_tilt`` of ``axis_cone``, random spin."""
    tilt = rng.normal(size=3)
    tilt -= axis_cone * (tilt @ axis_cone)
    tilt *= rng.uniform(0, max_tilt) / max(float(np.linalg.norm(tilt)), 1e-12)
    z = axis_angle_to_matrix(tilt) @ axis_cone
    spin = axis_angle_to_matrix(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)]))
    return _min_rotation(np.array([0.0, 0.0, 1.0]), z) @ spin


def _camera_T_board(system: System, rng: np.random.Generator, depth: tuple[float, float]) -> Array:
    assert system.camera is not None
    k = system.camera.intrinsics
    z = rng.uniform(*depth)
    u, v = rng.uniform(0.25, 0.75) * k.width, rng.uniform(0.25, 0.75) * k.height
    p = np.array([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z])
    R = _random_rotation_about(-p / np.linalg.norm(p), np.deg2rad(35.0), rng)
    return make_T(R, p)


def _in_image(system: System, p_camera: Array) -> bool:
    assert system.camera is not None
    k = system.camera.intrinsics
    z = p_camera[:, 2]
    u = k.fx * p_camera[:, 0] / z + k.cx
    v = k.fy * p_camera[:, 1] / z + k.cy
    return bool(np.all(z > 0.1) and np.all((u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)))


def simulate_handeye(
    system: System,
    robot: str,
    mode: str,
    n_poses: int,
    *,
    camera_pose: Array,
    board_pose: Array,
    board_points: Array | None = None,
    noise: DepthNoise | None = None,
    rng: np.random.Generator,
    depth: tuple[float, float] = (0.35, 1.2),
) -> HandEyeData:
    """Hand-eye samples for the true ``camera_pose`` / ``board_pose`` (see handeye module:
    world_T_camera + flange_T_board for eye_to_hand, flange_T_camera + world_T_board else).
    ``system.camera`` gives the intrinsics (image bounds)."""
    if system.camera is None:
        raise InputError("hand-eye simulation needs a camera (intrinsics) in the scenario")
    r = system.robot(robot)
    board = board_grid() if board_points is None else board_points
    qs: list[Array] = []
    pts: list[Array] = []
    for _ in range(400 * n_poses):
        if len(qs) == n_poses:
            break
        c_T_b = _camera_T_board(system, rng, depth)
        if mode == "eye_to_hand":
            w_T_f = camera_pose @ c_T_b @ inv_T(board_pose)
        else:
            w_T_f = board_pose @ inv_T(c_T_b) @ inv_T(camera_pose)
        q = ik_near(r, w_T_f, r.home)
        if q is None:
            continue
        p_cam = transform_points(c_T_b, board)
        if not _in_image(system, p_cam):
            continue
        qs.append(q)
        pts.append(p_cam)
    if len(qs) < n_poses:
        raise InputError(
            f"only {len(qs)} of {n_poses} hand-eye poses are reachable and visible; move the"
            " camera/board closer to the robot"
        )
    P = np.array(pts)
    if noise is not None:
        P = noise.apply(P, rng)
    return HandEyeData(robot, mode, board, np.array(qs), P)


def aim_chain(system: System, robot: str, aim_world: Array) -> Array:
    """Stacked joints of the chain up to ``robot`` that send the beam through every mirror
    centre (each turned minimally from home) and the last mirror's beam at ``aim_world``."""
    names = system.robot_names
    chain = system.robots[: names.index(robot) + 1]
    p, v = system.world_T_laser[:3, 3], system.world_T_laser[:3, 2]
    qs = []
    for i, r in enumerate(chain):
        w_T_m_home = r.world_T_base @ r.kinematics.fk(r.home) @ r.mirror.flange_T_mirror
        c = p + v * max(float(v @ (w_T_m_home[:3, 3] - p)), 0.05)
        if i + 1 < len(chain):
            nxt = chain[i + 1]
            goal = (nxt.world_T_base @ nxt.kinematics.fk(nxt.home) @ nxt.mirror.flange_T_mirror)[
                :3, 3
            ]
        else:
            goal = np.asarray(aim_world, dtype=float)
        out = (goal - c) / np.linalg.norm(goal - c)
        n = (out - v) / np.linalg.norm(out - v)
        # the mirror's +z is its face's normal at its centre, whatever the face's shape
        R = _min_rotation(w_T_m_home[:3, 2], n) @ w_T_m_home[:3, :3]
        q = ik_near(r, make_T(R, c) @ inv_T(r.mirror.flange_T_mirror), r.home)
        if q is None:
            raise InputError(
                f"cannot aim {r.name}'s mirror: the point {np.round(c, 3).tolist()} on the"
                " incoming beam is out of reach"
            )
        qs.append(q)
        p, v = c, out
    return np.concatenate(qs)


def simulate_beam(
    system: System,
    robot: str,
    n_poses: int,
    n_boards: int,
    *,
    aim_world: Array,
    noise: DepthNoise | None = None,
    rng: np.random.Generator,
) -> BeamData:
    """Spots of the true ``system`` on ``n_boards`` boards, ``n_poses`` valid poses each.

    Boards are squares (0.3 m) across the beam at 0.7-1.3 times the aimed distance, tilted
    up to 15 deg. With ``noise`` the spots get D435 noise in ``system.camera``'s frame.
    """
    if noise is not None and system.camera is None:
        raise InputError("the D435 noise model needs a camera in the scenario (its pose)")
    names = system.robot_names
    chain = System(system.world_T_laser, system.robots[: names.index(robot) + 1], system.camera)
    model = BeamModel(chain)
    q0 = aim_chain(chain, robot, aim_world)
    tr0 = model.trace(q0)
    h, d = tr0.hits[-1], tr0.dirs[-1]
    dist = float(np.linalg.norm(np.asarray(aim_world) - h))
    sigma = np.concatenate([PERTURB_SIGMA[: r.nq] for r in chain.robots])
    qs, spots, labels = [], [], []
    for b, frac in enumerate(np.linspace(0.7, 1.3, n_boards) if n_boards > 1 else [1.0]):
        R = _random_rotation_about(-d, np.deg2rad(15.0), rng)
        centre = h + d * dist * frac
        n_b, got = R[:, 2], 0
        for _ in range(500 * n_poses):
            if got == n_poses:
                break
            q = q0 + rng.normal(size=q0.size) * sigma
            tr = model.trace(q, centre, n_b)
            if not tr.valid:
                continue
            uv = R[:, :2].T @ (tr.spot - centre)
            if np.any(np.abs(uv) > BOARD_HALF):
                continue
            qs.append(q)
            spots.append(tr.spot)
            labels.append(b)
            got += 1
        if got < n_poses:
            raise InputError(f"board {b}: only {got} of {n_poses} valid poses hit the board")
    S = np.array(spots)
    if noise is not None:
        assert system.camera is not None
        c_T_w = inv_T(system.camera.world_T_camera)
        S = transform_points(
            system.camera.world_T_camera, noise.apply(transform_points(c_T_w, S), rng)
        )
    return BeamData(robot, np.array(qs), S, np.array(labels))


def default_handeye_truth(system: System, robot: str, mode: str) -> tuple[Array, Array]:
    """Plausible true poses for a simulated hand-eye dataset.

    eye_to_hand: the system's ``world_T_camera`` and a board 10 mm off the flange, facing
    out along flange z. eye_in_hand: the system's ``flange_T_camera`` when its camera is on
    ``robot``'s flange, else a camera 60 mm off the flange axis looking along flange z; and
    a board 0.4 m in front of it at the robot's home pose, facing it.
    """
    if mode == "eye_to_hand":
        if system.camera is None:
            raise InputError("eye_to_hand simulation needs a camera in the scenario")
        return system.camera.world_T_camera, make_T(p=[0.0, 0.0, 0.01])
    r = system.robot(robot)
    flange_T_camera = make_T(axis_angle_to_matrix([0.0, 0.0, np.pi / 2]), [0.0, 0.06, 0.02])
    cam = system.camera
    if cam is not None and cam.robot == robot and cam.flange_T_camera is not None:
        flange_T_camera = cam.flange_T_camera
    world_T_camera = r.world_T_base @ r.kinematics.fk(r.home) @ flange_T_camera
    camera_T_board = make_T(axis_angle_to_matrix([np.pi, 0.0, 0.0]), [0.0, 0.0, 0.4])
    return flange_T_camera, world_T_camera @ camera_T_board
