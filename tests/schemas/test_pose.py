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
