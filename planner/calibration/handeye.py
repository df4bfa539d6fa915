"""Hand-eye calibration (paper Eqs. 8-9): camera pose and marker-board pose, solved jointly.

Both modes share one model. At sample k the camera sees board point ``b`` at

    p_camera = Z @ A_k @ Y @ b

- ``eye_to_hand`` (fixed camera, board on the flange): Z = camera_T_world,
  A_k = world_T_flange(q_k), Y = flange_T_board.
- ``eye_in_hand`` (camera on the flange, board fixed): Z = camera_T_flange,
  A_k = flange_T_world(q_k), Y = world_T_board.

The camera pose reported is X = inv(Z) (``world_T_camera`` or ``flange_T_camera``).
Closed-form start: each sample's ``camera_T_board`` by point-set registration, then
X B_k = A_k Y solved linearly (rotations from the null space of the Kronecker system,
translations by least squares). Refinement: Levenberg-Marquardt on all marker points
through a named CasADi residual, optionally with a Huber or Cauchy loss.
Units: metres, radians; standard deviations are in the local frame of each pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np

from planner.calibration.lsq import (
    LsqResult,
    delta_T,
    exp_T,
    levenberg_marquardt,
    null_directions,
)
from planner.errors import CalibrationError, DatasetError
from planner.model.system import System
from planner.model.transforms import Array, inv_T, make_T, matrix_to_axis_angle

MODES = ("eye_to_hand", "eye_in_hand")
MIN_SAMPLES = 3
MIN_ROTATION_RMS = np.deg2rad(2.0)  # below this, an axis counts as not excited
PARAM_NAMES = [f"camera.{a}" for a in ("rx", "ry", "rz", "tx", "ty", "tz")] + [
    f"board.{a}" for a in ("rx", "ry", "rz", "tx", "ty", "tz")
]


@dataclass(frozen=True)
class HandEyeData:
    """A hand-eye dataset (docs/conventions.md: Calibration data) as arrays.

    ``board_points`` (P, 3) in the board frame; ``q`` (K, nq); ``points_camera``
    (K, P, 3) in the camera frame, NaN where a marker was not seen.
    """

    robot: str
    mode: str
    board_points: Array
    q: Array
    points_camera: Array


@dataclass(frozen=True)
class HandEyeResult:
    """Calibrated poses, residuals (metres) and uncertainties.

    ``camera_pose`` is ``world_T_camera`` (eye_to_hand) or ``flange_T_camera``;
    ``board_pose`` is ``flange_T_board`` or ``world_T_board``. ``std`` maps
    ``camera_rotation``/``camera_translation``/``board_rotation``/``board_translation``
    to 3 standard deviations (rad or m, in that pose's own frame).
    """

    mode: str
    camera_pose: Array
    board_pose: Array
    point_residuals: Array  # (M,) norms of every used marker residual
    sample_residuals: Array  # (K,) RMS marker residual per sample (NaN if none seen)
    std: dict[str, Array]
    singular_values: Array
    iterations: int
    converged: bool
    warnings: list[str] = field(default_factory=list)

    @property
    def camera_key(self) -> str:
        return "world_T_camera" if self.mode == "eye_to_hand" else "flange_T_camera"

    @property
    def board_key(self) -> str:
        return "flange_T_board" if self.mode == "eye_to_hand" else "world_T_board"


# --- closed form ----------------------------------------------------------------------------
def fit_rigid(src: Array, dst: Array) -> Array:
    """``dst_T_src`` minimising |dst - T src| over point pairs (Kabsch / Umeyama, no scale)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return make_T(R, cd - R @ cs)


def project_so3(M: Array) -> Array:
    """Nearest rotation matrix (Frobenius) of a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def solve_ax_yb(A: list[Array], B: list[Array]) -> tuple[Array, Array]:
    """Closed-form X, Y with X B_k = A_k Y (exact for exact data; needs >= 2 rotation axes)."""
    rows = [
        np.hstack([np.kron(b[:3, :3].T, np.eye(3)), -np.kron(np.eye(3), a[:3, :3])])
        for a, b in zip(A, B, strict=True)
    ]
    _, _, Vt = np.linalg.svd(np.vstack(rows))
    v = Vt[-1]
    RX, RY = v[:9].reshape(3, 3, order="F"), v[9:].reshape(3, 3, order="F")
    det = np.linalg.det(RX)
    alpha = np.sign(det) / abs(det) ** (1.0 / 3.0)
    RX, RY = project_so3(alpha * RX), project_so3(alpha * RY)
    M = np.vstack([np.hstack([np.eye(3), -a[:3, :3]]) for a in A])
    rhs = np.concatenate([a[:3, 3] - RX @ b[:3, 3] for a, b in zip(A, B, strict=True)])
    t = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return make_T(RX, t[:3]), make_T(RY, t[3:])


# --- CasADi residual ------------------------------------------------------------------------
@lru_cache(maxsize=8)
def handeye_residual() -> ca.Function:
    """``r = (E(dz) Z0) A (Y0 E(dy)) b - p`` and its Jacobian w.r.t. ``[dz; dy]``."""
    dz, dy = ca.SX.sym("dz", 6), ca.SX.sym("dy", 6)
    Z0, A, Y0 = ca.SX.sym("Z0", 4, 4), ca.SX.sym("A", 4, 4), ca.SX.sym("Y0", 4, 4)
    b, p = ca.SX.sym("b", 3), ca.SX.sym("p", 3)
    T = ca.mtimes([delta_T(dz), Z0, A, Y0, delta_T(dy)])
    r = T[:3, :3] @ b + T[:3, 3] - p
    inputs = {"dz": dz, "dy": dy, "Z0": Z0, "A": A, "Y0": Y0, "b": b, "p": p}
    outputs = {"r": r, "J": ca.jacobian(r, ca.vertcat(dz, dy))}
    return ca.Function("handeye_residual", inputs | outputs, list(inputs), list(outputs))


@lru_cache(maxsize=64)
def _mapped(n: int) -> ca.Function:
    return handeye_residual().map(n, "serial")


def _retract(state: tuple[Array, Array], dx: Array) -> tuple[Array, Array]:
    Z, Y = state
    return exp_T(dx[:6]) @ Z, Y @ exp_T(dx[6:12])


# --- excitation -----------------------------------------------------------------------------
def excitation_warnings(A: list[Array]) -> list[str]:
    """Warn when the flange rotations do not excite two independent axes."""
    w = np.array([matrix_to_axis_angle(A[0][:3, :3].T @ a[:3, :3]) for a in A[1:]])
    s, Vt = np.linalg.svd(w, full_matrices=False)[1:]
    rms = s / np.sqrt(len(w))
    if rms[0] < MIN_ROTATION_RMS:
        return [
            f"degenerate poses: flange rotations are below {np.rad2deg(MIN_ROTATION_RMS):.1f} deg"
            " RMS; rotate the flange about two different axes"
        ]
    if rms[1] < MIN_ROTATION_RMS:
        ax = ", ".join(f"{x:+.2f}" for x in Vt[0])
        return [
            f"degenerate poses: all flange rotations are about one axis [{ax}] (first pose's"
            " flange frame); missing excitation: rotations about an axis perpendicular to it"
        ]
    return []


def _world_T_flange(system: System, robot: str, q: Array) -> Array:
    r = system.robot(robot)
    return r.world_T_base @ r.kinematics.fk(q)


# long: the hand-eye fit's stages (closed-form start, joint least squares, residuals, result) in order
def calibrate_handeye(
    data: HandEyeData,
    system: System,
    *,
    loss: str = "none",
    loss_scale: float = 0.005,
) -> HandEyeResult:
    """Solve the camera and board poses of a hand-eye dataset (see module docstring)."""
    if data.mode not in MODES:
        raise DatasetError(f"mode {data.mode!r}: expected one of {', '.join(MODES)}")
    try:
        system.robot(data.robot)
    except KeyError as exc:
        raise DatasetError(str(exc.args[0]), "robot") from exc
    K = len(data.q)
    if K < MIN_SAMPLES:
        raise DatasetError(f"{K} samples: hand-eye calibration needs at least {MIN_SAMPLES}")
    W = [_world_T_flange(system, data.robot, q) for q in data.q]
    A = W if data.mode == "eye_to_hand" else [inv_T(w) for w in W]

    seen = np.all(np.isfinite(data.points_camera), axis=2)  # (K, P)
    init_A, init_B = [], []
    for k in range(K):
        src, dst = data.board_points[seen[k]], data.points_camera[k][seen[k]]
        if len(src) >= 3 and np.linalg.svd(src - src.mean(0), compute_uv=False)[1] > 1e-6:
            init_A.append(A[k])
            init_B.append(fit_rigid(src, dst))
    if len(init_A) < MIN_SAMPLES:
        raise DatasetError(
            f"only {len(init_A)} samples see >= 3 non-collinear markers; need {MIN_SAMPLES}"
        )
    warnings = excitation_warnings(init_A)
    X0, Y0 = solve_ax_yb(init_A, init_B)

    kk, jj = np.nonzero(seen)
    M = len(kk)
    A_h = np.hstack([A[k] for k in kk])
    b_h, p_h = data.board_points[jj].T, data.points_camera[kk, jj].T
    fn = _mapped(M)

    def linearize(state: tuple[Array, Array]) -> tuple[Array, Array]:
        Z, Y = state
        out = fn(dz=np.zeros(6), dy=np.zeros(6), Z0=Z, A=A_h, Y0=Y, b=b_h, p=p_h)
        r_a = np.asarray(out["r"]).T.ravel()
        J_a = np.asarray(out["J"]).reshape(3, M, 12).transpose(1, 0, 2).reshape(3 * M, 12)
        return r_a, J_a

    res: LsqResult[tuple[Array, Array]] = levenberg_marquardt(
        linearize, _retract, (inv_T(X0), Y0), loss=loss, loss_scale=loss_scale
    )
    missing = null_directions(res.singular_values, res.right_vectors, PARAM_NAMES)
    if missing:
        raise CalibrationError(
            "hand-eye poses leave directions unobservable: "
            + "; ".join(missing)
            + (f" ({warnings[0]})" if warnings else ""),
            missing,
        )
    Z, Y = res.state
    norms = np.linalg.norm(res.residuals.reshape(-1, 3), axis=1)
    per_sample = np.full(K, np.nan)
    for k in range(K):
        sel = kk == k
        if np.any(sel):
            per_sample[k] = np.sqrt(np.mean(norms[sel] ** 2))
    sd = np.sqrt(np.maximum(np.diag(res.covariance), 0.0))
    return HandEyeResult(
        mode=data.mode,
        camera_pose=inv_T(Z),
        board_pose=Y,
        point_residuals=norms,
        sample_residuals=per_sample,
        std={
            "camera_rotation": sd[:3],
            "camera_translation": sd[3:6],
            "board_rotation": sd[6:9],
            "board_translation": sd[9:12],
        },
        singular_values=res.singular_values,
        iterations=res.iterations,
        converged=res.converged,
        warnings=warnings,
    )
