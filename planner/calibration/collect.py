"""Planning a calibration data collection on the real (or simulated) robot.

- Poses. Hand-eye: board poses inside the camera's view (0.35-1.2 m, tilted up to 35 deg),
  reached by analytic IK nearest home (:func:`planner.calibration.simulate.simulate_handeye`
  with the *nominal* geometry). Beam: small joint perturbations around the configuration
  that aims the chain at ``aim`` (the board), kept when the nominal beam stays valid and
  lands within the board (:func:`planner.calibration.simulate.simulate_beam`).
- Conditioning (:func:`handeye_plan`, :func:`beam_plan`). Of ``oversample`` x n
  candidates, greedy selection keeps the n that give the best-conditioned calibration
  Jacobian at the nominal solution: the hand-eye residual
  Jacobian w.r.t. the 12 pose corrections, rotation columns scaled by :data:`LEVER` (m) so
  rad and m compare; the beam residual Jacobian w.r.t. the observable laser/mirror
  corrections. The condition number (largest / smallest singular value) is reported.
  The paper's design, :func:`random_handeye_plan`, takes n random candidates as drawn.
- Moves. Each pose is reached by a minimum-jerk joint move (peak speed ``speed`` rad/s),
  sampled at 500 Hz, checked with the swept collision check
  (:func:`planner.safety.sweep.check_sweep`) before it is sent; a move that fails is skipped.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from planner.errors import InputError
from planner.model.system import System
from planner.model.transforms import Array, inv_T
from schemas import defaults

LEVER = 0.5  # m: rotation columns are scaled by this to compare with translations
RATE = defaults.SERVO_RATE_HZ  # Hz, samples of a move
#: rad/s, the default peak joint speed of a collection move, and the range allowed
SPEED, SPEED_RANGE = 0.3, (0.01, 1.0)


class Move(NamedTuple):
    """A joint move of one robot: times (s), q, qd, qdd (K x nq)."""

    t: Array
    q: Array
    qd: Array
    qdd: Array


def min_jerk_move(q0: Array, q1: Array, speed: float, rate: float = RATE,
                  acceleration: Array | float | None = None) -> Move:  # fmt: skip
    """Minimum-jerk joint move from ``q0`` to ``q1`` whose fastest joint peaks at ``speed``
    (rad/s), slower when a joint would pass its ``acceleration`` (rad/s^2, per joint): a
    minimum-jerk move of ``dq`` in ``T`` s peaks at 1.875 dq / T and 10 / sqrt(3) dq / T^2."""
    q0, q1 = np.asarray(q0, dtype=float), np.asarray(q1, dtype=float)
    dq = q1 - q0
    duration = max(0.5, 1.875 * float(np.max(np.abs(dq))) / speed)
    if acceleration is not None:
        need = 10 / np.sqrt(3) * np.abs(dq) / np.asarray(acceleration, dtype=float)
        duration = max(duration, float(np.sqrt(np.max(need))))
    t = np.arange(0.0, duration + 0.5 / rate, 1.0 / rate)
    x = t / duration
    s = 10 * x**3 - 15 * x**4 + 6 * x**5
    sd = (30 * x**2 - 60 * x**3 + 30 * x**4) / duration
    sdd = (60 * x - 180 * x**2 + 120 * x**3) / duration**2
    return Move(t, q0 + s[:, None] * dq, sd[:, None] * dq, sdd[:, None] * dq)


def handeye_jacobian(
    system: System, robot: str, mode: str, qs: Array, board: Array, camera: Array, board_pose: Array
) -> Array:
    """Stacked hand-eye residual Jacobian (3 K P x 12) at the nominal poses, scaled."""
    from planner.calibration.handeye import handeye_residual

    r = system.robot(robot)
    fn = handeye_residual()
    rows = []
    for q in qs:
        w = r.world_T_base @ r.kinematics.fk(q)
        if mode == "eye_to_hand":
            Z0, A, Y0 = inv_T(camera), w, board_pose
        else:
            Z0, A, Y0 = inv_T(camera), inv_T(w), board_pose
        T = Z0 @ A @ Y0
        for b in board:
            p = T[:3, :3] @ b + T[:3, 3]
            rows.append(np.asarray(fn(np.zeros(6), np.zeros(6), Z0, A, Y0, b, p)[1]))
    J = np.vstack(rows)
    J[:, [0, 1, 2, 6, 7, 8]] *= LEVER  # delta_T: rotation first (rad), then translation
    return J


def condition(J: Array) -> float:
    """Largest / smallest singular value of ``J`` (inf when rank deficient)."""
    sv = np.linalg.svd(J, compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")


def _gram_condition(G: Array) -> float:
    ev = np.linalg.eigvalsh(G)
    return float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else float("inf")


def select_conditioned(grams: Array, n: int) -> tuple[list[int], float]:
    """Greedy choice of ``n`` candidates by their Jacobian blocks' Gram matrices ``J_i^T J_i``
    (C x m x m): start from the best pair of the first few, add the candidate that lowers
    the condition number of the stacked Jacobian most; (indices, condition number)."""
    C = len(grams)
    if n > C:
        raise ValueError(f"{C} candidates for {n} poses")
    chosen = [0, 1]
    G = grams[0] + grams[1]
    rest = list(range(2, C))
    while len(chosen) < n:
        scores = [_gram_condition(G + grams[i]) for i in rest]
        best = rest[int(np.argmin(scores))]
        chosen.append(best)
        rest.remove(best)
        G = G + grams[best]
    return chosen, _gram_condition(G)


def _handeye_candidates(system: System, robot: str, mode: str, n: int, board: Array,
                        board_pose: Array, rng: np.random.Generator,
                        feasible: Callable[[Array], bool] | None) -> Array:  # fmt: skip
    """``n`` random board-visible, reachable hand-eye poses (rad) on the nominal geometry
    (:func:`planner.calibration.simulate.simulate_handeye`), those ``feasible`` rejects
    dropped (so fewer may remain)."""
    from planner.calibration.simulate import simulate_handeye

    assert system.camera is not None
    cam = system.camera.world_T_camera
    cand = simulate_handeye(system, robot, mode, n, camera_pose=cam, board_pose=board_pose,
                            board_points=board, rng=rng).q  # fmt: skip
    if feasible is not None:
        cand = cand[[bool(feasible(q)) for q in cand]]
    return cand


def _grams(system: System, robot: str, mode: str, qs: Array, board: Array,
           board_pose: Array) -> Array:  # fmt: skip
    """Per pose, the Gram matrix ``J^T J`` of its scaled hand-eye Jacobian block."""
    assert system.camera is not None
    cam = system.camera.world_T_camera
    out = []
    for q in qs:
        J = handeye_jacobian(system, robot, mode, q[None], board, cam, board_pose)
        out.append(J.T @ J)
    return np.array(out)


def handeye_plan(
    system: System,
    robot: str,
    mode: str,
    n: int,
    board: Array,
    board_pose: Array,
    rng: np.random.Generator,
    oversample: int = 3,
    feasible: Callable[[Array], bool] | None = None,
) -> tuple[Array, float]:
    """n well-conditioned hand-eye poses (rad) and the Jacobian's condition number;
    ``feasible`` (e.g. a static collision check) filters the candidates first."""
    cand = _handeye_candidates(system, robot, mode, oversample * n, board, board_pose, rng,
                               feasible)  # fmt: skip
    chosen, cond = select_conditioned(_grams(system, robot, mode, cand, board, board_pose), n)
    return cand[chosen], cond


def random_handeye_plan(
    system: System,
    robot: str,
    mode: str,
    n: int,
    board: Array,
    board_pose: Array,
    rng: np.random.Generator,
    oversample: int = 3,
    feasible: Callable[[Array], bool] | None = None,
) -> tuple[Array, float]:
    """The paper's design: n random hand-eye poses (rad), no selection, and the condition
    number they happen to give. Poses are drawn as :func:`handeye_plan`'s candidates are
    (board pose uniform in the middle half of the image, depth 0.35-1.2 m, tilt up to
    35 deg, random spin; rejected when unreachable or the board leaves the image), so they
    are uniform within the reachable, board-visible set; the first n that ``feasible``
    keeps are taken (of ``oversample`` x n drawn when there is a ``feasible``)."""
    k = n if feasible is None else oversample * n
    cand = _handeye_candidates(system, robot, mode, k, board, board_pose, rng, feasible)
    if len(cand) < n:
        raise ValueError(f"{len(cand)} feasible random poses for {n}")
    qs = cand[:n]
    G = _grams(system, robot, mode, qs, board, board_pose).sum(axis=0)
    return qs, _gram_condition(G)


def beam_plan(
    system: System,
    robot: str,
    n: int,
    aim: Array,
    rng: np.random.Generator,
    oversample: int = 3,
    feasible: Callable[[Array], bool] | None = None,
) -> tuple[Array, float]:
    """n well-conditioned beam poses (stacked chain joints) aiming at ``aim`` (world, m), for
    the plane fit of :func:`planner.calibration.beam.calibrate_beam` (which refuses a curved
    mirror: so does this, :func:`~planner.calibration.beam.plane_fit_refusal`)."""
    from planner.calibration.beam import (
        OBSERVABLE_LASER,
        OBSERVABLE_MIRROR,
        _mapped,
        plane_fit_refusal,
    )
    from planner.calibration.simulate import simulate_beam

    if (why := plane_fit_refusal(system, robot)) is not None:
        raise InputError(why, f"robot {robot}")

    data = simulate_beam(system, robot, oversample * n, 1, aim_world=aim, rng=rng)
    if feasible is not None:
        keep = [bool(feasible(q)) for q in data.q]
        data = type(data)(data.robot, data.q[keep], data.spots_world[keep], data.boards[keep])
    names = system.robot_names
    idx = names.index(robot)
    chain = system.robots[: idx + 1]
    kin, surfaces = tuple(r.kinematics for r in chain), tuple(r.mirror.surface for r in chain)
    cols = (OBSERVABLE_LASER if idx == 0 else []) + OBSERVABLE_MIRROR
    bases = np.hstack([r.world_T_base for r in chain])
    mounts = np.hstack([r.mirror.flange_T_mirror for r in chain])

    k = len(data.q)
    out = _mapped(kin, surfaces, k)(data.q.T, np.zeros(6), np.zeros(6), system.world_T_laser, bases,
                          mounts, data.spots_world.T)  # fmt: skip
    Jk: Array = np.asarray(out[1]).reshape(3, k, 12).transpose(1, 0, 2)  # (k, 3, 12)
    Jk[..., [0, 1, 2, 6, 7, 8]] *= LEVER
    Jk = Jk[..., cols]
    chosen, cond = select_conditioned(np.einsum("kri,krj->kij", Jk, Jk), n)
    return data.q[chosen], cond
