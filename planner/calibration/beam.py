"""Laser line + mirror plane from 3D laser spots (paper Eq. 10), through the planner's beam graph.

Each sample is a spot measured in the world at recorded joints ``q`` (all robots of the
chain up to the calibrated one). The residual is the planner's own ``beam`` CasADi
function evaluated with the spot as target and no normal: the vector from the spot to the
closest point of the last ray. The spot may equally be a known fiducial that the spot was
driven onto at ``q`` (the paper's design): the residual and the solver are the same. Unknowns are perturbations of ``world_T_laser`` (right,
laser frame) and of the calibrated robot's ``flange_T_mirror`` (right, mirror frame).

Identifiability: a spot constrains only the *line* of the laser and the *plane* of the
mirror. Of the 12 pose parameters, the laser's roll and slide along its beam and the
mirror's in-plane slide and spin are unobservable; :func:`calibrate_beam` finds them from
the singular values of the full 12-column Jacobian, checks they are exactly these five,
solves only the 7 observable ones (laser: 2 tilts, 2 offsets across the beam; mirror: 2
tilts, the offset along its normal) and then fixes the gauge (:func:`apply_gauge`):
the laser origin is the point of the calibrated line closest to the nominal origin; the
mirror centre is the nominal (CAD) centre, or a measured one (fiducials), projected onto
the calibrated plane; both orientations are the nominal ones turned by the smallest
rotation onto the calibrated beam / normal. Units: metres, radians.

N > 1 (:func:`calibrate_chain`): the mirrors are calibrated one after the other in beam
order, each from spots of the beam leaving it, with the laser and the earlier mirrors held
at their calibrated values (the residual is the same graph through the whole chain up to
the calibrated robot); only the last mirror's 3 observable parameters are solved.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np

from planner.beam.graph import beam_function, chain_symbols
from planner.calibration.lsq import (
    delta_T,
    describe_direction,
    exp_T,
    levenberg_marquardt,
    null_directions,
)
from planner.errors import CalibrationError, DatasetError, InputError
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
from planner.model.system import System
from planner.model.transforms import Array, axis_angle_to_matrix, make_T

FULL_NAMES = [f"laser.{a}" for a in ("rx", "ry", "rz", "tx", "ty", "tz")] + [
    f"mirror.{a}" for a in ("rx", "ry", "rz", "tx", "ty", "tz")
]
OBSERVABLE_LASER = [0, 1, 3, 4]  # tilts about laser x/y, offsets across the beam
OBSERVABLE_MIRROR = [6, 7, 11]  # tilts about mirror x/y, offset along the normal
GAUGE = {
    "laser.rz": "laser roll about its own beam: irrelevant, kept from the scenario",
    "laser.tz": "laser origin slides along its beam: fixed at the point of the calibrated"
    " line closest to the nominal laser origin",
    "mirror.rz": "mirror spin about its normal: kept from the scenario (CAD)",
    "mirror.txy": "mirror centre slides in its plane: fixed at the nominal (CAD) centre, or"
    " the measured fiducial centre, projected onto the calibrated plane",
}
REL_TOL = 1e-9


@dataclass(frozen=True)
class BeamData:
    """A beam dataset: ``q`` (K, nq of the chain, rad), ``spots_world`` (K, 3, m),
    ``boards`` (K,) placement labels; ``camera_spots`` counts the spots that were given in
    the camera frame and mapped to the world with the scenario's camera pose."""

    robot: str
    q: Array
    spots_world: Array
    boards: Array
    camera_spots: int = 0


@dataclass(frozen=True)
class BeamResult:
    """Calibrated (gauge-fixed) poses, residuals in metres, observable std devs.

    ``std`` maps observable parameter names (``laser.rx`` ... ``mirror.tz``) to one
    standard deviation (rad or m); ``unobservable`` lists the directions found from the
    Jacobian with the gauge that fixed each.
    """

    robot: str
    world_T_laser: Array | None  # None when the laser is not an unknown
    flange_T_mirror: Array
    residuals: Array  # (K,) spot-to-ray distances
    std: dict[str, float]
    unobservable: list[dict[str, str]]
    singular_values: Array
    iterations: int
    converged: bool
    warnings: list[str] = field(default_factory=list)
    detected: list[str] = field(default_factory=list)  # null directions of the full Jacobian
    #: covariance of the observable increments (names and order of ``std``), applied on the
    #: right of the poses as ``T @ exp_T(d)`` (laser: first 6 of d, mirror: last 6), and the
    #: same for a unit residual noise (``covariance = sigma**2 * unit_covariance``)
    covariance: Array | None = None
    unit_covariance: Array | None = None
    sigma: float = float("nan")  # m: residual noise the fit's residuals give


def plane_fit_refusal(system: System, robot: str) -> str | None:
    """Why this calibration cannot fit ``robot``'s mirror, in one line (None: it can). It fits
    a mirror *plane*: its gauge (in-plane slide and spin unobservable) and its 3 observable
    parameters hold for a flat face only (a sphere shows its in-plane slide and has a
    radius), so any other :class:`~planner.model.mirror.Surface` is refused, not fitted."""
    surface = system.robot(robot).mirror.surface
    if surface.is_flat:
        return None
    return (f"the beam calibration fits a mirror plane; {robot}'s mirror is {surface!r}, not"
            " flat: measure its mount another way")  # fmt: skip


@lru_cache(maxsize=16)
def beam_residual(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...]
) -> ca.Function:
    """Spot residual through :func:`planner.beam.graph.beam_function` for the last mirror's mount
    (each mirror's face as ``surfaces`` says; the fitted last one is flat, a plane).

    inputs: q, d_laser (6), d_mirror (6), world_T_laser, world_T_base (4x4N),
    flange_T_mirror (4x4N), spot (3); outputs: r (3), J (3x12, w.r.t. [d_laser; d_mirror]).
    """
    N = len(kinematics)
    sym = chain_symbols(kinematics)
    dl, dm = ca.SX.sym("d_laser", 6), ca.SX.sym("d_mirror", 6)
    spot = ca.SX.sym("spot", 3)
    mounts = sym.flange_T_mirror
    last = mounts[:, 4 * (N - 1) :] @ delta_T(dm)
    mounts_d = ca.horzcat(mounts[:, : 4 * (N - 1)], last) if N > 1 else last
    out = beam_function(kinematics, surfaces)(
        q=sym.q,
        world_T_laser=sym.world_T_laser @ delta_T(dl),
        world_T_base=sym.world_T_base,
        flange_T_mirror=mounts_d,
        roi_half=ca.DM.ones(2, N),
        target=spot,
        normal=ca.DM.zeros(3),
    )
    r = out["residual"]
    inputs = {"q": sym.q, "d_laser": dl, "d_mirror": dm, "world_T_laser": sym.world_T_laser,
              "world_T_base": sym.world_T_base, "flange_T_mirror": mounts, "spot": spot}  # fmt: skip
    outputs = {"r": r, "J": ca.jacobian(r, ca.vertcat(dl, dm))}
    return ca.Function("beam_calibration_residual", inputs | outputs, list(inputs), list(outputs))


@lru_cache(maxsize=64)
def _mapped(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...], n: int
) -> ca.Function:
    return beam_residual(kinematics, surfaces).map(n, "serial")


def _min_rotation(a: Array, b: Array) -> Array:
    """Smallest rotation taking unit vector a onto unit vector b."""
    v, c = np.cross(a, b), float(np.dot(a, b))
    s = float(np.linalg.norm(v))
    if s < 1e-15:
        return np.eye(3) if c > 0 else axis_angle_to_matrix(np.pi * _perpendicular(a))
    return axis_angle_to_matrix(v / s * np.arctan2(s, c))


def _perpendicular(a: Array) -> Array:
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    p = np.cross(a, e)
    return p / np.linalg.norm(p)


def apply_gauge(
    world_T_laser: Array | None,
    flange_T_mirror: Array,
    nominal_world_T_laser: Array,
    nominal_flange_T_mirror: Array,
    mirror_centre: Array | None = None,
) -> tuple[Array | None, Array]:
    """Fix the unobservable directions as stated in the module docstring.

    ``mirror_centre`` (3, flange frame) replaces the CAD centre when it was measured.
    """
    L = None
    if world_T_laser is not None:
        d, p = world_T_laser[:3, 2], world_T_laser[:3, 3]
        p0 = nominal_world_T_laser[:3, 3]
        R = _min_rotation(nominal_world_T_laser[:3, 2], d) @ nominal_world_T_laser[:3, :3]
        L = make_T(R, p + d * float(d @ (p0 - p)))
    n, c = flange_T_mirror[:3, 2], flange_T_mirror[:3, 3]
    c0 = nominal_flange_T_mirror[:3, 3] if mirror_centre is None else np.asarray(mirror_centre)
    R = _min_rotation(nominal_flange_T_mirror[:3, 2], n) @ nominal_flange_T_mirror[:3, :3]
    return L, make_T(R, c0 - n * float(n @ (c0 - c)))


# long: the beam fit's stages (gauge, initial guess, robust least squares, covariance, result) in the order the docstring gives them
def calibrate_beam(
    data: BeamData,
    system: System,
    *,
    loss: str = "none",
    loss_scale: float = 0.005,
    starts: int = 4,
    seed: int = 0,
    mirror_centre: Array | None = None,
) -> BeamResult:
    """Laser line (if ``data.robot`` is first in the chain) and the robot's mirror plane (a
    curved mirror is refused: :func:`plane_fit_refusal`)."""
    names = system.robot_names
    if data.robot not in names:
        raise DatasetError(f"unknown robot {data.robot!r}; robots: {', '.join(names)}", "robot")
    if (why := plane_fit_refusal(system, data.robot)) is not None:
        raise InputError(why, f"robot {data.robot}")
    idx = names.index(data.robot)
    chain = system.robots[: idx + 1]
    kin = tuple(r.kinematics for r in chain)
    surfaces = tuple(r.mirror.surface for r in chain)
    nq = sum(k.nq for k in kin)
    K = len(data.q)
    if data.q.ndim != 2 or data.q.shape[1] != nq:
        raise DatasetError(f"q: expected {nq} joints per sample (robots {names[: idx + 1]})")
    cols = (OBSERVABLE_LASER if idx == 0 else []) + OBSERVABLE_MIRROR
    if len(cols) >= 2 * K:
        raise DatasetError(
            f"{K} spots give {2 * K} equations for {len(cols)} unknowns; need at least"
            f" {len(cols) // 2 + 1} spots (better: several boards, 16 poses each)"
        )
    if not np.all(np.isfinite(data.spots_world)):
        raise DatasetError("spots contain non-finite values")
    L_nom = system.world_T_laser
    M_nom = chain[-1].mirror.flange_T_mirror
    bases = np.hstack([r.world_T_base for r in chain])
    others = np.hstack([r.mirror.flange_T_mirror for r in chain[:-1]]) if idx else np.zeros((4, 0))
    fn = _mapped(kin, surfaces, K)
    q_h, spot_h = data.q.T, data.spots_world.T

    def full_linearize(L: Array, M: Array) -> tuple[Array, Array]:
        out = fn(q=q_h, d_laser=np.zeros(6), d_mirror=np.zeros(6), world_T_laser=L,
                 world_T_base=bases, flange_T_mirror=np.hstack([others, M]), spot=spot_h)  # fmt: skip
        J_a = np.asarray(out["J"]).reshape(3, K, 12).transpose(1, 0, 2).reshape(3 * K, 12)
        return np.asarray(out["r"]).T.ravel(), J_a

    def linearize(state: tuple[Array, Array]) -> tuple[Array, Array]:
        r, J = full_linearize(*state)
        return r, J[:, cols]

    def retract(state: tuple[Array, Array], dx: Array) -> tuple[Array, Array]:
        full = np.zeros(12)
        full[cols] = dx
        return state[0] @ exp_T(full[:6]), state[1] @ exp_T(full[6:])

    rng = np.random.default_rng(seed)
    best = None
    for s in range(max(1, starts)):
        state = (L_nom, M_nom)
        if s:  # multi-start: +-3 deg tilts, +-10 mm offsets around the nominal values
            d = np.concatenate([rng.uniform(-0.05, 0.05, 3), rng.uniform(-0.01, 0.01, 3)])
            e = np.concatenate([rng.uniform(-0.05, 0.05, 3), rng.uniform(-0.01, 0.01, 3)])
            state = (L_nom @ exp_T(d) if idx == 0 else L_nom, M_nom @ exp_T(e))
        res = levenberg_marquardt(
            linearize, retract, state, dof_per_group=2, loss=loss, loss_scale=loss_scale
        )
        cost = float(np.sum(res.weights * np.sum(res.residuals.reshape(-1, 3) ** 2, axis=1)))
        if best is None or cost < best[0] - 1e-18:
            best = (cost, res)
    assert best is not None
    res = best[1]

    # identifiability: the full Jacobian's null space must be exactly the gauge
    cand = list(range(12)) if idx == 0 else list(range(6, 12))
    J_full = full_linearize(*res.state)[1][:, cand]
    sv_full, Vt_full = np.linalg.svd(J_full, full_matrices=False)[1:]
    n_null = int(np.sum(sv_full < REL_TOL * sv_full[0]))
    expected_null = len(cand) - len(cols)
    cand_names = [FULL_NAMES[c] for c in cand]
    found = [describe_direction(Vt_full[-i - 1], cand_names) for i in range(n_null)]
    missing = null_directions(res.singular_values, res.right_vectors, [FULL_NAMES[c] for c in cols])
    boards = np.unique(data.boards)
    if missing or n_null > expected_null:
        hint = f" with a single board placement ({boards[0]})" if len(boards) == 1 else ""
        raise CalibrationError(
            f"the spots{hint} leave directions unobservable beyond the gauge: "
            + "; ".join(missing or found[expected_null:])
            + " (add board placements at other distances and more varied mirror poses)",
            missing or found,
        )
    warnings = []
    cond = res.singular_values[0] / res.singular_values[-1]
    if cond > 1e6:
        weak = describe_direction(res.right_vectors[-1], [FULL_NAMES[c] for c in cols])
        warnings.append(f"weakly observable: {weak} (condition number {cond:.1e})")
    if len(boards) == 1:
        warnings.append("single board placement: use several at different distances")

    L_est, M_est = res.state
    L_out, M_out = apply_gauge(L_est if idx == 0 else None, M_est, L_nom, M_nom, mirror_centre)
    sd = np.sqrt(np.maximum(np.diag(res.covariance), 0.0))
    gauge_rows = [{"direction": k, "gauge": v} for k, v in GAUGE.items()]
    if idx:
        gauge_rows = gauge_rows[2:]
    return BeamResult(
        robot=data.robot,
        world_T_laser=L_out,
        flange_T_mirror=M_out,
        residuals=np.linalg.norm(res.residuals.reshape(-1, 3), axis=1),
        std={FULL_NAMES[c]: float(v) for c, v in zip(cols, sd, strict=True)},
        unobservable=gauge_rows,
        singular_values=res.singular_values,
        iterations=res.iterations,
        converged=res.converged,
        warnings=warnings,
        detected=found,
        covariance=np.asarray(res.covariance),
        unit_covariance=_unit_covariance(res.singular_values, res.right_vectors),
        sigma=float(res.sigma),
    )


def _unit_covariance(sv: Array, Vt: Array) -> Array:
    """``(J^T J)^-1`` from the Jacobian's singular values and right vectors (directions of
    singular values under 1e-12 of the largest left out, as the fit's covariance does)."""
    inv_sv2 = np.where(sv > sv[0] * 1e-12, 1.0 / np.maximum(sv, 1e-300) ** 2, 0.0)
    return np.asarray((Vt.T * inv_sv2) @ Vt)


def with_beam_result(system: System, result: BeamResult) -> System:
    """``system`` with a beam calibration's laser (when it was an unknown) and mirror mount."""
    return system.with_params(
        world_T_laser=result.world_T_laser, flange_T_mirror={result.robot: result.flange_T_mirror}
    )


def calibrate_chain(
    system: System, collect: Callable[[System, str], BeamData], **options: Any
) -> tuple[System, list[BeamResult]]:
    """Every mirror of the chain in beam order, each through :func:`calibrate_beam`.

    For each robot, ``collect(system, robot)`` returns its spots (the beam leaving that
    robot's mirror: the robots after it out of the beam) given the system calibrated so
    far, which the fit then holds: the first dataset gives the laser line and mirror 1's
    plane, the k-th mirror k's plane with the laser and mirrors 1..k-1 at their calibrated
    values. ``options`` go to :func:`calibrate_beam`. Returns the calibrated system and
    the results in beam order.
    """
    results = []
    for name in system.robot_names:
        data = collect(system, name)
        if data.robot != name:
            raise DatasetError(f"collected data for {data.robot!r}, expected {name!r}", "robot")
        result = calibrate_beam(data, system, **options)
        system = with_beam_result(system, result)
        results.append(result)
    return system, results
