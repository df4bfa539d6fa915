"""Levenberg-Marquardt on a manifold, with robust (IRLS) losses and covariance.

The calibrations linearise a CasADi residual at the current estimate (increment zero),
solve for an increment and *retract* it onto the estimate (rigid transforms are updated
with the exact exponential), so any parameterisation whose first derivative at zero is
right converges quadratically.

Residuals come in groups of ``group`` rows (one 3D point each); a robust loss reweights
whole groups by the norm of their residual (metres).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

from planner.errors import CalibrationError
from planner.model.transforms import Array, axis_angle_to_matrix, make_T

if TYPE_CHECKING:
    import casadi as ca

S = TypeVar("S")

LOSSES = ("none", "huber", "cauchy")


def delta_T(d: ca.SX) -> ca.SX:
    """Symbolic rigid increment ``[I + skew(w), t]`` of ``d = [w (rad); t (m)]``: first order,
    with the exact derivative at zero (what the linearised residuals differentiate)."""
    import casadi as ca

    R = ca.SX.eye(3) + ca.skew(d[:3])
    return ca.vertcat(ca.horzcat(R, d[3:]), ca.horzcat(0, 0, 0, 1))


def exp_T(d: Array) -> Array:
    """Numeric rigid increment of ``d = [w (rad); t (m)]``: rotation exp(skew(w)),
    translation t; the retraction matching :func:`delta_T` (same derivative at zero)."""
    return make_T(axis_angle_to_matrix(d[:3]), d[3:])


def robust_weights(norms: Array, loss: str, scale: float) -> Array:
    """IRLS weight of each residual group for a loss of ``scale`` metres."""
    if loss == "none":
        return np.ones_like(norms)
    u = norms / scale
    if loss == "huber":
        return np.where(u <= 1.0, 1.0, 1.0 / np.maximum(u, 1e-300))
    if loss == "cauchy":
        return 1.0 / (1.0 + u * u)
    raise ValueError(f"unknown loss {loss!r}; expected one of {', '.join(LOSSES)}")


@dataclass(frozen=True)
class LsqResult(Generic[S]):
    """Outcome of :func:`levenberg_marquardt`.

    ``residuals`` (m,) and ``jacobian`` (m, n) at the solution, ``weights`` per group,
    ``covariance`` (n, n) of the increment, ``singular_values`` of the weighted Jacobian.
    """

    state: S
    residuals: Array
    jacobian: Array
    weights: Array
    covariance: Array
    singular_values: Array
    right_vectors: Array
    iterations: int
    converged: bool
    sigma: float


# long: one Levenberg-Marquardt loop: step, damping update and the stopping tests read together
def levenberg_marquardt(
    linearize: Callable[[S], tuple[Array, Array]],
    retract: Callable[[S, Array], S],
    state: S,
    *,
    group: int = 3,
    dof_per_group: int = 3,
    loss: str = "none",
    loss_scale: float = 0.005,
    max_iter: int = 100,
    tol: float = 1e-14,
) -> LsqResult[S]:
    """Minimise the (robustly weighted) sum of squared residuals from ``state``.

    ``linearize(state) -> (r, J)`` gives residuals and their Jacobian w.r.t. a local
    increment at zero; ``retract(state, dx)`` applies an increment. ``dof_per_group`` is
    the number of independent rows per group (2 for a point-to-ray distance in 3D).
    """
    lam = 1e-6
    r, J = linearize(state)
    w = robust_weights(np.linalg.norm(r.reshape(-1, group), axis=1), loss, loss_scale)
    cost = float(np.sum(w * np.sum(r.reshape(-1, group) ** 2, axis=1)))
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        sw = np.repeat(np.sqrt(w), group)
        Jw, rw = J * sw[:, None], r * sw
        H, g = Jw.T @ Jw, Jw.T @ rw
        scale = np.maximum(np.diag(H), 1e-12)
        step_ok = False
        for _ in range(30):
            dx = -np.linalg.solve(H + lam * np.diag(scale), g)
            cand = retract(state, dx)
            r_c, J_c = linearize(cand)
            w_c = robust_weights(np.linalg.norm(r_c.reshape(-1, group), axis=1), loss, loss_scale)
            cost_c = float(np.sum(w_c * np.sum(r_c.reshape(-1, group) ** 2, axis=1)))
            if cost_c <= cost or np.linalg.norm(dx) < tol:
                step_ok = True
                break
            lam *= 10.0
        if not step_ok:
            break
        decrease = cost - cost_c
        state, r, J, w, cost = cand, r_c, J_c, w_c, cost_c
        lam = max(lam / 10.0, 1e-12)
        if np.linalg.norm(dx) < tol or (decrease <= 1e-15 * max(cost, 1e-300) and it > 3):
            converged = True
            break
        if cost < 1e-30:
            converged = True
            break
    sw = np.repeat(np.sqrt(w), group)
    Jw = J * sw[:, None]
    _, sv, Vt = np.linalg.svd(Jw, full_matrices=False)
    n = J.shape[1]
    m_eff = dof_per_group * (len(r) // group)
    if m_eff <= n:
        raise CalibrationError(
            f"{len(r) // group} measurements give {m_eff} equations for {n} unknowns"
        )
    sigma2 = cost / (m_eff - n)
    inv_sv2 = np.where(sv > sv[0] * 1e-12, 1.0 / np.maximum(sv, 1e-300) ** 2, 0.0)
    covariance = sigma2 * (Vt.T * inv_sv2) @ Vt
    return LsqResult(
        state=state,
        residuals=r,
        jacobian=J,
        weights=w,
        covariance=covariance,
        singular_values=sv,
        right_vectors=Vt,
        iterations=it,
        converged=converged,
        sigma=float(np.sqrt(sigma2)),
    )


def describe_direction(vector: Array, names: list[str], top: int = 3) -> str:
    """Human-readable parameter combination, e.g. ``0.71*laser.tz - 0.71*mirror.tz``."""
    order = np.argsort(-np.abs(vector))[:top]
    parts = [f"{vector[i]:+.2f}*{names[i]}" for i in order if abs(vector[i]) > 0.05]
    return " ".join(parts)


def null_directions(sv: Array, Vt: Array, names: list[str], rel_tol: float = 1e-9) -> list[str]:
    """Parameter combinations the data cannot determine (relative singular value < tol)."""
    if sv.size == 0:
        return []
    small = np.nonzero(sv < rel_tol * sv[0])[0]
    missing = max(0, Vt.shape[0] - sv.size)
    out = [describe_direction(Vt[i], names) for i in small]
    out += ["(fewer equations than unknowns)"] * missing
    return out
