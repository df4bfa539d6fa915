"""Rigid transforms as 4x4 numpy arrays.

``a_T_b`` maps coordinates in frame b to frame a, ``p_a = a_T_b @ p_b``. Rotations in files
are fixed-axis X-Y-Z (URDF) ``rpy``: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``; quaternions are
``[x, y, z, w]``. The rotation conversions live in :mod:`schemas.rotations` (the file formats
need them) and are re-exported here.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from schemas.rotations import (
    Array,
    make_T,
    matrix_to_quat,
    matrix_to_rpy,
    nearest_rotation,
    quat_to_matrix,
    rot_x,
    rot_y,
    rot_z,
    rpy_to_matrix,
)

__all__ = [
    "Array",
    "axis_angle_to_matrix",
    "inv_T",
    "look_at",
    "make_T",
    "matrix_to_axis_angle",
    "matrix_to_quat",
    "matrix_to_rpy",
    "nearest_rotation",
    "quat_to_matrix",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_angle",
    "rpy_to_matrix",
    "transform_points",
]


def inv_T(T: ArrayLike) -> Array:
    """Inverse of a rigid transform (exact, no general matrix inverse)."""
    T = np.asarray(T, dtype=float)
    R, p = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ p)


def transform_points(a_T_b: ArrayLike, p_b: ArrayLike) -> Array:
    """Map points ``(..., 3)`` from frame b to frame a."""
    T = np.asarray(a_T_b, dtype=float)
    p = np.asarray(p_b, dtype=float)
    return p @ T[:3, :3].T + T[:3, 3]


def axis_angle_to_matrix(axis_angle: ArrayLike) -> Array:
    """Rodrigues: rotation by |w| about w/|w| (the SO(3) exponential)."""
    w = np.asarray(axis_angle, dtype=float)
    th = float(np.linalg.norm(w))
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-12:
        return np.eye(3) + K
    K = K / th
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * (K @ K)


def matrix_to_axis_angle(R: ArrayLike) -> Array:
    """SO(3) logarithm as an axis-angle vector (angle in [0, pi])."""
    R = np.asarray(R, dtype=float)
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    th = float(np.arccos(c))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-9:
        return v / 2
    if np.pi - th < 1e-6:
        # near pi: axis from the symmetric part
        B = (R + np.eye(3)) / 2
        axis = np.sqrt(np.clip(np.diag(B), 0, None))
        i = int(np.argmax(axis))
        axis = B[:, i] / np.sqrt(B[i, i])
        return axis * th
    return v * th / (2 * np.sin(th))


def rotation_angle(R: ArrayLike) -> float:
    """Angle (rad) of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(np.asarray(R)) - 1) / 2, -1.0, 1.0)))


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> Array:
    """``world_T_frame`` for a frame at ``eye`` whose +z points at ``target``.

    x is chosen perpendicular to ``up`` (for an OpenCV camera: x right, y down).
    """
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.column_stack([x, y, z]), eye)


def plane_bases(normals: ArrayLike) -> Array:
    """Orthonormal bases ``[n, e1, e2]`` (columns) of the planes with normals ``normals``
    ((K, 3) -> (K, 3, 3); any length, normalised here): ``e1 = n x a`` normalised with
    ``a`` the x axis (the y axis when n is within ~26 deg of x), ``e2 = n x e1``."""
    N = np.asarray(normals, dtype=float)
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    A = np.where((np.abs(N[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(N, A)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([N, e1, np.cross(N, e1)], axis=2)


def plane_basis(normal: ArrayLike) -> Array:
    """:func:`plane_bases` of one normal (3,): the 3 x 3 matrix ``[n, e1, e2]`` (the same
    arithmetic on plain floats: numpy calls on 3-vectors cost ~1 µs each, and the path's
    continuation chain asks for a basis per step)."""
    n = np.asarray(normal, dtype=float).reshape(-1)
    if n.shape != (3,):
        raise ValueError(f"a plane normal has 3 components, got {n.shape}")
    nx, ny, nz = (float(v) for v in n)
    r = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not 0.0 < r < math.inf:  # zero or non-finite: numpy's NaN (and warning) as before
        return np.asarray(plane_bases(n[None, :])[0])
    nx, ny, nz = nx / r, ny / r, nz / r
    ax, ay, az = (1.0, 0.0, 0.0) if abs(nx) < 0.9 else (0.0, 1.0, 0.0)
    ex, ey, ez = ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax  # n x a
    r = math.sqrt(ex * ex + ey * ey + ez * ez)
    ex, ey, ez = ex / r, ey / r, ez / r
    fx, fy, fz = ny * ez - nz * ey, nz * ex - nx * ez, nx * ey - ny * ex  # n x e1
    return np.array([[nx, ex, fx], [ny, ey, fy], [nz, ez, fz]])
