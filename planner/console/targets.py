"""The operator's target list and the TargetRequest built from it.

A :class:`TargetList` is an ordered tuple of picked :class:`Target` (world point, optional
unit normal); every edit returns a new list. :func:`build_request` turns it into a
TargetRequest dict (in the camera frame for a fixed camera: the picks are its cloud's
points): separate ``points``, or one ``path`` through the targets in order — a
polyline (the planner resamples it and marks corners sharper than its corner angle) or a
smooth curve, which the console samples itself (a cubic spline through the targets,
:func:`planner.io.strokes.mark_path`) and sends as a dense polyline.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.errors import InputError
from planner.io.strokes import mark_path
from planner.model.transforms import Array
from planner.service.client import make_request
from schemas import defaults


class Mode(enum.StrEnum):
    """How the targets are visited: each one (``points``), or swept as one path."""

    POINTS = "points"
    POLYLINE = "polyline"
    SMOOTH = "smooth"


@dataclass(frozen=True)
class Target:
    """One picked target: ``p`` (world, m) and its unit surface ``n`` (world) or None."""

    p: tuple[float, float, float]
    n: tuple[float, float, float] | None = None

    def label(self, k: int) -> str:
        """``#k  x, y, z mm`` (world)."""
        x, y, z = (1e3 * c for c in self.p)
        return f"#{k}  {x:.1f}, {y:.1f}, {z:.1f} mm"


@dataclass(frozen=True)
class TargetList:
    """Targets in visiting order."""

    items: tuple[Target, ...] = ()

    def __len__(self) -> int:
        return len(self.items)

    def add(self, p: Array, n: Array | None = None) -> TargetList:
        """A list with ``p`` (world, m) and its normal appended."""
        t = Target(_vec(p), None if n is None else _vec(np.asarray(n) / np.linalg.norm(n)))
        return TargetList((*self.items, t))

    def delete(self, k: int) -> TargetList:
        self._check(k)
        return TargetList(self.items[:k] + self.items[k + 1 :])

    def move(self, k: int, step: int) -> TargetList:
        """Target ``k`` moved ``step`` places (clamped to the ends)."""
        self._check(k)
        j = min(max(k + step, 0), len(self.items) - 1)
        items = list(self.items)
        items.insert(j, items.pop(k))
        return TargetList(tuple(items))

    def points(self) -> Array:
        return np.array([t.p for t in self.items], dtype=float).reshape(-1, 3)

    def normals(self) -> Array | None:
        """K x 3 unit normals, or None unless every target has one."""
        if not self.items or any(t.n is None for t in self.items):
            return None
        return np.array([t.n for t in self.items], dtype=float)

    def _check(self, k: int) -> None:
        if not 0 <= k < len(self.items):
            raise InputError(f"no target #{k} (the list has {len(self.items)})", "targets")


def path_points(targets: TargetList, mode: Mode, spacing: float = defaults.PATH_SPACING_M
                ) -> tuple[Array, Array | None]:  # fmt: skip
    """Points (and normals) to send for ``mode``: the targets themselves, or for a smooth
    path the spline through them sampled every ``spacing`` m."""
    P, N = targets.points(), targets.normals()
    if mode is not Mode.SMOOTH or len(P) < 3:
        return P, N

    marked = mark_path(P, spacing, normals=N, smooth=True)
    return marked.points, marked.normals


def build_request(
    targets: TargetList,
    mode: Mode,
    *,
    execute: bool = False,
    closed_loop: bool = False,
    dwell: float | None = None,
    use_normals: bool = True,
    request_id: str | None = None,
    camera_T_world: Array | None = None,
) -> dict[str, Any]:
    """The TargetRequest for the list: in the world frame, or with ``camera_T_world`` (the
    calibrated pose of a fixed camera, inverted) in the camera frame, where the camera saw
    the picked cloud points (the console drew them through that pose): the planner then
    lands them on the surface that carries them and measures a closed loop in that frame.
    InputError for an empty list, a path of fewer than two targets, or a negative dwell."""
    if len(targets) == 0:
        raise InputError("no targets: click the point cloud to add one", "targets")
    if mode is not Mode.POINTS and len(targets) < 2:
        raise InputError(f"a path needs >= 2 targets, got {len(targets)}", "targets")
    if dwell is not None and not (np.isfinite(dwell) and dwell >= 0):
        raise InputError(f"dwell must be >= 0 s, got {dwell}", "dwell")
    P, N = path_points(targets, mode)
    frame = "world"
    if camera_T_world is not None:
        T = np.asarray(camera_T_world, dtype=float)
        P, N = P @ T[:3, :3].T + T[:3, 3], None if N is None else N @ T[:3, :3].T
        frame = "camera"
    req = make_request(
        P,
        frame=frame,
        normals=N if use_normals else None,
        path=mode is not Mode.POINTS,
        execute=execute,
        request_id=request_id,
    )
    req["closed_loop"] = bool(closed_loop)
    if dwell is not None and mode is Mode.POINTS:
        req["dwell"] = float(dwell)
    return req


def _vec(p: Array) -> tuple[float, float, float]:
    a = np.asarray(p, dtype=float).reshape(3)
    if not np.all(np.isfinite(a)):
        raise InputError(f"target {a.tolist()} is not finite", "targets")
    return (float(a[0]), float(a[1]), float(a[2]))
