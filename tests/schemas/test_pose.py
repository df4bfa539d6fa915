"""Pose forms -> matrices, checked against scipy's independent rotation code."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from schemas.common import Pose

angles = st.lists(st.floats(-np.pi, np.pi), min_size=3, max_size=3)
xyz = st.lists(st.floats(-2, 2), min_size=3, max_size=3)


def test_defaults_are_identity() -> None:
    assert np.array_equal(Pose().matrix(), np.eye(4))
    T = Pose.model_validate({"xyz": [1, 2, 3]}).matrix()
    assert np.allclose(T[:3, 3], [1, 2, 3]) and np.allclose(T[:3, :3], np.eye(3))


def test_rpy_deg_pitch_minus_90_maps_z_to_minus_x() -> None:
    T = Pose.model_validate({"rpy_deg": [0, -90, 0]}).matrix()
    assert np.allclose(T[:3, :3] @ [0, 0, 1], [-1, 0, 0], atol=1e-12)


@given(angles, xyz)
def test_rpy_is_fixed_axis_xyz(rpy: list[float], p: list[float]) -> None:
    T = Pose.model_validate({"xyz": p, "rpy": rpy}).matrix()
    expected = Rotation.from_euler("xyz", rpy).as_matrix()  # extrinsic x, then y, then z
    assert np.allclose(T[:3, :3], expected, atol=1e-12)
    assert np.allclose(T[:3, 3], p)
    T_deg = Pose.model_validate({"xyz": p, "rpy_deg": np.degrees(rpy).tolist()}).matrix()
    assert np.allclose(T_deg, T, atol=1e-12)


@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1))
def test_quat_is_xyzw_and_normalised(q: list[float]) -> None:
    pose = Pose.model_validate({"quat": q})
    assert np.isclose(np.linalg.norm(pose.quat), 1.0)
    expected = Rotation.from_quat(q).as_matrix()  # scipy: scalar last
    assert np.allclose(pose.matrix()[:3, :3], expected, atol=1e-12)


@given(angles, xyz)
def test_from_matrix_round_trip(rpy: list[float], p: list[float]) -> None:
    T = Pose.model_validate({"xyz": p, "rpy": rpy}).matrix()
    pose = Pose.from_matrix(T)
    assert pose.to_dict() == {"matrix": T.tolist()}
    assert np.array_equal(Pose.model_validate(pose.to_dict()).matrix(), T)


def test_quat_90_about_z() -> None:
    s = np.sqrt(0.5)
    T = Pose.model_validate({"xyz": [0, 0, 1], "quat": [0, 0, s, s]}).matrix()
    assert np.allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0])


@pytest.mark.parametrize(
    "data, reason",
    [
        ({"quat": [0, 0, 0, 0]}, "quaternion has length"),
        ({"quat": [0, 0, 0, 1e-7]}, "quaternion has length"),
        ({"rpy": [0, 0, 0], "quat": [0, 0, 0, 1]}, "only one of"),
        ({"matrix": np.eye(4).tolist(), "xyz": [0, 0, 0]}, "not allowed with matrix"),
        ({"matrix": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()}, "determinant"),
        ({"matrix": (np.eye(4) * 1.01).tolist()}, "orthonormal"),
        ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}, "last row"),
        ({"matrix": np.eye(3).tolist()}, "expected 4 rows, got 3"),
        ({"xyz": [0, 0]}, "expected 3 numbers, got 2"),
        ({"xyz": [0, 0, float("nan")]}, "finite"),
        ({"xyz": [0, 0, "1"]}, "expected a number"),
        ({"xyz": [0, 0, True]}, "expected a number"),
        ({"rpy_degs": [0, 0, 0]}, "Extra inputs"),
    ],
)
def test_invalid_poses(data: dict[str, object], reason: str) -> None:
    with pytest.raises(ValidationError, match=reason):
        Pose.model_validate(data)


def test_rigid_tolerance() -> None:
    R = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R + 1e-5
    Pose.model_validate({"matrix": T.tolist()})  # within 1e-4: made a rotation
    T[:3, :3] = R + 1e-3
    with pytest.raises(ValidationError, match=r"max \|R\^T R - I\| = 0.00"):
        Pose.model_validate({"matrix": T.tolist()})


def test_numpy_arrays_accepted() -> None:
    pose = Pose.model_validate({"xyz": np.array([1.0, 2.0, 3.0]), "matrix": None})
    assert pose.xyz == [1.0, 2.0, 3.0]


# --- matrices printed with six decimals, radians/degrees mix-ups ---------------------------
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1))
def test_matrix_printed_with_six_decimals_loads_as_the_nearest_rotation(q: list[float]) -> None:
    R = Rotation.from_quat(q).as_matrix()
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, [0.4, -0.2, 0.7]
    printed = [[float(f"{x:.6f}") for x in row] for row in T]
    M = Pose.model_validate({"matrix": printed}).matrix()
    R_loaded = M[:3, :3]
    assert np.max(np.abs(R_loaded.T @ R_loaded - np.eye(3))) < 1e-12
    assert np.linalg.det(R_loaded) > 0
    assert np.max(np.abs(R_loaded - R)) < 1e-5
    assert np.array_equal(M[3], [0, 0, 0, 1]) and np.allclose(M[:3, 3], T[:3, 3], atol=1e-6)


def test_matrix_beyond_tolerance_says_how_far_off() -> None:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix()
    T[0, :3] *= 1.002  # a row 0.2 % too long: |R^T R - I| about 4e-3
    with pytest.raises(ValidationError) as info:
        Pose.model_validate({"matrix": T.tolist()})
    err = float(np.max(np.abs(T[:3, :3].T @ T[:3, :3] - np.eye(3))))
    assert f"= {err:.3g} > 0.0001" in str(info.value)


@pytest.mark.parametrize(
    "rpy, index", [([40, 0, 0], 0), ([0, -90, 0], 1), ([0, 0, 6.3], 2), ([0, 0, -7], 2)]
)
def test_rpy_beyond_two_pi_suggests_rpy_deg(rpy: list[float], index: int) -> None:
    with pytest.raises(ValidationError, match=rf"rpy\.{index}: .* beyond 2 pi.*rpy_deg"):
        Pose.model_validate({"rpy": rpy})
    Pose.model_validate({"rpy": [0, 0, 2 * np.pi]})  # a full turn is still radians


def test_quaternion_length_written_is_kept_for_warnings() -> None:
    assert Pose.model_validate({"quat": [0, 0, 90, 1]}).quat_length == pytest.approx(
        np.hypot(90, 1)
    )
    assert Pose.model_validate({"quat": [0, 0, 1, 1]}).quat_length == pytest.approx(np.sqrt(2))
    assert Pose.model_validate({"rpy": [0, 0, 1]}).quat_length is None
