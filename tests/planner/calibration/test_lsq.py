"""Levenberg-Marquardt core: against closed-form least squares and known weights."""

from __future__ import annotations

import numpy as np
import pytest

from planner.calibration.lsq import levenberg_marquardt, null_directions, robust_weights
from planner.errors import CalibrationError


def test_robust_weights_known_values():
    norms = np.array([0.5, 1.0, 2.0, 4.0])
    assert np.allclose(robust_weights(norms, "none", 1.0), 1.0)
    assert np.allclose(robust_weights(norms, "huber", 1.0), [1.0, 1.0, 0.5, 0.25])
    assert np.allclose(robust_weights(norms, "cauchy", 1.0), [0.8, 0.5, 0.2, 1 / 17])
    with pytest.raises(ValueError, match="unknown loss"):
        robust_weights(norms, "tukey", 1.0)


def test_linear_problem_matches_lstsq_and_covariance():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(30, 4))
    b = rng.normal(size=30)
    res = levenberg_marquardt(lambda x: (A @ x - b, A), lambda x, dx: x + dx, np.zeros(4))
    x_ref, ssr, *_ = np.linalg.lstsq(A, b, rcond=None)
    assert np.allclose(res.state, x_ref, atol=1e-12)
    cov_ref = ssr[0] / (30 - 4) * np.linalg.inv(A.T @ A)
    assert np.allclose(res.covariance, cov_ref, rtol=1e-9)
    assert res.sigma == pytest.approx(np.sqrt(ssr[0] / 26), rel=1e-12)


def test_nonlinear_exponential_fit_recovers_exact_parameters():
    t = np.linspace(0, 2, 12)
    y = 1.7 * np.exp(-0.8 * t)

    def lin(x):
        e = np.exp(x[1] * t)
        return x[0] * e - y, np.column_stack([e, x[0] * t * e])

    res = levenberg_marquardt(
        lin, lambda x, dx: x + dx, np.array([1.0, 0.0]), group=1, dof_per_group=1
    )
    assert np.allclose(res.state, [1.7, -0.8], atol=1e-12)


def test_rank_deficiency_is_reported_and_too_few_equations_raise():
    A = np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    res = levenberg_marquardt(
        lambda x: (A @ x - 1.0, A), lambda x, dx: x + dx, np.zeros(2), group=1, dof_per_group=1
    )
    found = null_directions(res.singular_values, res.right_vectors, ["a", "b"])
    assert len(found) == 1 and "a" in found[0] and "b" in found[0]
    with pytest.raises(CalibrationError, match="equations"):
        levenberg_marquardt(
            lambda x: (A[:1] @ x, A[:1]),
            lambda x, dx: x + dx,
            np.zeros(2),
            group=1,
            dof_per_group=1,
        )


def test_rigid_increments_agree_to_first_order():
    import casadi as ca

    from planner.calibration.lsq import delta_T, exp_T

    d = ca.SX.sym("d", 6)
    f = ca.Function("f", [d], [ca.reshape(delta_T(d), 16, 1)])
    x = np.array([0.1, -0.2, 0.3, 0.01, 0.02, -0.03])
    E = np.asarray(f(x)).reshape(4, 4, order="F")
    skew = np.array([[0, -0.3, -0.2], [0.3, 0, -0.1], [0.2, 0.1, 0]])
    np.testing.assert_allclose(E[:3, :3], np.eye(3) + skew, atol=1e-15)
    np.testing.assert_allclose(E[:3, 3], x[3:], atol=1e-15)
    np.testing.assert_allclose(E[3], [0, 0, 0, 1])
    # exp_T: a proper rotation by |w| about w/|w| (Rodrigues), translation t
    R = exp_T(x)[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(R @ x[:3], x[:3], atol=1e-15)
    assert np.arccos((np.trace(R) - 1) / 2) == pytest.approx(np.linalg.norm(x[:3]), rel=1e-12)
    np.testing.assert_allclose(exp_T(x)[:3, 3], x[3:])
    # the same derivative at zero: central differences of exp_T vs the symbolic Jacobian
    J = np.asarray(ca.Function("J", [d], [ca.jacobian(ca.reshape(delta_T(d), 16, 1), d)])(0))
    h = 1e-6
    for i in range(6):
        e = np.zeros(6)
        e[i] = h
        fd = (exp_T(e) - exp_T(-e)).reshape(-1, order="F") / (2 * h)
        np.testing.assert_allclose(fd, J[:, i], atol=1e-9)
