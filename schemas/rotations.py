"""Rotation conversions the file formats need: fixed-axis rpy, quaternions, 4x4 matrices.

Conventions: rotations in files are fixed-axis X-Y-Z (URDF) ``rpy`` in radians,
``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``; quaternions are ``[x, y, z, w]``; a transform
``a_T_b`` maps coordinates in frame b to frame a, ``p_a = a_T_b @ p_b``. This is the one
implementation; :mod:`planner.model.transforms` re-exports it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def rot_x(a: float) -> Array:
    """Rotation by ``a`` rad about x."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> Array:
    """Rotation by ``a`` rad about y."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> Array:
    """Rotation by ``a`` rad about z."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy_to_matrix(rpy: ArrayLike) -> Array:
    """Rotation matrix of fixed-axis roll-pitch-yaw (radians)."""
    r, p, y = np.asarray(rpy, dtype=float)
    return rot_z(y) @ rot_y(p) @ rot_x(r)


def matrix_to_rpy(R: ArrayLike) -> Array:
    """Inverse of :func:`rpy_to_matrix` (radians, pitch in [-pi/2, pi/2])."""
    R = np.asarray(R, dtype=float)
    pitch = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    if np.hypot(R[0, 0], R[1, 0]) < 1e-12:  # gimbal lock: put everything in roll
        return np.array([np.arctan2(-R[1, 2], R[1, 1]), pitch, 0.0])
    return np.array([np.arctan2(R[2, 1], R[2, 2]), pitch, np.arctan2(R[1, 0], R[0, 0])])


def quat_to_matrix(quat: ArrayLike) -> Array:
    """Rotation matrix of a quaternion ``[x, y, z, w]`` (normalised here)."""
    x, y, z, w = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R: ArrayLike) -> Array:
    """Quaternion ``[x, y, z, w]`` with w >= 0 of a rotation matrix."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i] = s / 4
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
    out = np.array(q)
    return out if out[3] >= 0 else -out


def nearest_rotation(R: ArrayLike) -> Array:
    """The rotation matrix nearest ``R`` in the Frobenius norm (SVD projection, det +1)."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=float))
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    return np.asarray(U @ D @ Vt, dtype=float)


def make_T(R: ArrayLike | None = None, p: ArrayLike | None = None) -> Array:
    """Homogeneous 4x4 transform from a rotation matrix and a translation (m)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, dtype=float)
    if p is not None:
        T[:3, 3] = np.asarray(p, dtype=float)
    return T
