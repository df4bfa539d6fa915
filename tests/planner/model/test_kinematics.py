"""CasADi FK built from the Pinocchio model vs Pinocchio's own FK and Jacobians, and vs DH."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from planner.errors import InputError
from planner.model.kinematics import UR5E_DH, RobotKinematics


def dh_fk(q: np.ndarray) -> np.ndarray:
    """Standard DH forward kinematics written independently of the URDF."""
    T = np.eye(4)
    for th, d, a, al in zip(q, UR5E_DH["d"], UR5E_DH["a"], UR5E_DH["alpha"], strict=True):
        ct, st, ca_, sa = np.cos(th), np.sin(th), np.cos(al), np.sin(al)
        T = T @ np.array(
            [
                [ct, -st * ca_, st * sa, a * ct],
                [st, ct * ca_, -ct * sa, a * st],
                [0, sa, ca_, d],
                [0, 0, 0, 1],
            ]
        )
    return T


@pytest.fixture(scope="module")
def kin() -> RobotKinematics:
    return RobotKinematics.ur5e()


@pytest.fixture(scope="module")
def qs() -> np.ndarray:
    return np.random.default_rng(42).uniform(-2 * np.pi, 2 * np.pi, (1000, 6))


def test_spec_check_value(kin: RobotKinematics) -> None:
    q = np.array([0, -np.pi / 2, 0, -np.pi / 2, 0, 0])
    np.testing.assert_allclose(kin.fk(q)[:3, 3], [0, -0.2329, 1.0794], atol=1e-4)
    np.testing.assert_allclose(np.array(kin.casadi_fk(q))[:3, 3], [0, -0.2329, 1.0794], atol=1e-4)


def test_joint_names_and_limits(kin: RobotKinematics) -> None:
    assert kin.joint_names == (
        "shoulder_pan",
        "shoulder_lift",
        "elbow",
        "wrist_1",
        "wrist_2",
        "wrist_3",
    )
    np.testing.assert_allclose(kin.upper, [2 * np.pi] * 2 + [np.pi] + [2 * np.pi] * 3)


def test_casadi_fk_matches_pinocchio_and_dh(kin: RobotKinematics, qs: np.ndarray) -> None:
    batched = kin.casadi_fk.map(len(qs))
    T_all = np.array(batched(qs.T))  # 4 x 4000
    for k, q in enumerate(qs):
        T_ca = T_all[:, 4 * k : 4 * k + 4]
        T_pin = kin.fk(q)
        assert np.abs(T_ca - T_pin).max() < 1e-12
        assert np.abs(T_pin - dh_fk(q)).max() < 1e-12


def test_casadi_jacobian_matches_pinocchio(kin: RobotKinematics, qs: np.ndarray) -> None:
    q = ca.SX.sym("q", 6)
    T = kin.casadi_fk_expr(q)
    R = T[:3, :3]
    Jp = ca.jacobian(T[:3, 3], q)
    # angular velocity columns: vee(dR/dq_i @ R^T)
    cols = []
    for i in range(6):
        W = ca.mtimes(ca.jacobian(ca.vec(R), q[i]).reshape((3, 3)), R.T)
        cols.append(ca.vertcat(W[2, 1], W[0, 2], W[1, 0]))
    J = ca.Function("J", [q], [ca.vertcat(Jp, ca.horzcat(*cols))]).map(len(qs))
    J_all = np.array(J(qs.T))
    for k, qk in enumerate(qs):
        assert np.abs(J_all[:, 6 * k : 6 * k + 6] - kin.jacobian(qk)).max() < 1e-12


def test_jacobian_matches_finite_differences(kin: RobotKinematics) -> None:
    q = np.array([0.3, -1.1, 1.2, -1.6, -1.4, 0.5])
    J = kin.jacobian(q)
    eps = 1e-7
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = eps
        Tp, Tm = kin.fk(q + dq), kin.fk(q - dq)
        np.testing.assert_allclose((Tp[:3, 3] - Tm[:3, 3]) / (2 * eps), J[:3, i], atol=1e-8)
        W = (Tp[:3, :3] - Tm[:3, :3]) / (2 * eps) @ kin.fk(q)[:3, :3].T
        np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], J[3:, i], atol=1e-8)


def test_analytic_ik_branches_reproduce_pose(kin: RobotKinematics) -> None:
    q = np.array([0.3, -1.2, 1.4, -1.7, -1.5, 0.4])
    sols = kin.analytic_ik(kin.fk(q))
    assert len(sols) == 8
    assert min(np.abs(s - q).max() for s in sols) < 1e-9
    for s in sols:
        assert np.abs(kin.fk(s) - kin.fk(q)).max() < 1e-12


def test_user_urdf_with_calibration_offsets(kin: RobotKinematics, tmp_path) -> None:
    from planner.model.kinematics import ur5e_urdf_path

    text = ur5e_urdf_path().read_text()
    text = text.replace('xyz="-0.425 0 0.0"', 'xyz="-0.4262 0.0008 0.0011"')
    path = tmp_path / "ur5e_calibrated.urdf"
    path.write_text(text)
    cal = RobotKinematics.from_urdf(path)
    assert not cal.has_analytic_ik
    q = np.array([0.3, -1.2, 1.4, -1.7, -1.5, 0.4])
    shift = np.linalg.norm(cal.fk(q)[:3, 3] - kin.fk(q)[:3, 3])
    assert 1e-3 < shift < 3e-3  # a factory-calibration-sized offset
    assert np.abs(np.array(cal.casadi_fk(q)) - cal.fk(q)).max() < 1e-12
    # independent check: the offset equals the rotated link-2 correction
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    np.testing.assert_allclose(cal.fk(q), data.oMf[model.getFrameId("tool0")].homogeneous)


def test_missing_urdf_is_input_error(tmp_path) -> None:
    with pytest.raises(InputError, match="not found"):
        RobotKinematics.from_urdf(tmp_path / "nope.urdf")
