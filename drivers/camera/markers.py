"""Calibration-board markers seen by the camera (hand-eye data collection).

:func:`detect_charuco` finds the inner chessboard corners of a ChArUco board (OpenCV
``aruco.CharucoDetector``: sub-pixel corners, identified by the ArUco markers around them,
so a partly hidden board still gives correct ids) on the colour image, and deprojects each
with the aligned depth: a plane fitted to the valid depths of a ``window`` x ``window`` patch
around the corner (the black/white edges make single depth pixels unreliable), intersected
with the corner's pixel ray. Corners without enough depth are NaN (not seen).

The board frame is OpenCV's: corner ``i`` at ``board.getChessboardCorners()[i]`` (m, z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.model.system import Intrinsics
from planner.model.transforms import Array


@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board: squares (x, y), square and marker side (m), ArUco dictionary name."""

    squares_x: int = 7
    squares_y: int = 5
    square: float = 0.04
    marker: float = 0.03
    dictionary: str = "DICT_5X5_100"

    def board(self) -> Any:
        import cv2

        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square,
                                      self.marker, d)  # fmt: skip

    def points(self) -> Array:
        """Corner positions in the board frame (P x 3, m)."""
        return np.asarray(self.board().getChessboardCorners(), dtype=float)


def detect_charuco(
    rgb: Array, depth_m: Array, k: Intrinsics, spec: CharucoSpec, window: int = 9
) -> Array:
    """Board corners in the camera optical frame (P x 3, m), NaN rows where not seen."""
    import cv2

    board = spec.board()
    n = len(board.getChessboardCorners())
    out = np.full((n, 3), np.nan)
    gray = cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2GRAY)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    if ids is None:
        return out
    for (u, v), i in zip(corners.reshape(-1, 2), ids.ravel(), strict=True):
        p = _deproject_plane(float(u), float(v), depth_m, k, window)
        if p is not None:
            out[int(i)] = p
    return out


def _deproject_plane(
    u: float, v: float, depth_m: Array, k: Intrinsics, window: int
) -> Array | None:
    h, w = depth_m.shape
    r = window // 2
    u0, v0 = round(u), round(v)
    vs, us = np.mgrid[max(0, v0 - r) : min(h, v0 + r + 1), max(0, u0 - r) : min(w, u0 + r + 1)]
    z = depth_m[vs, us]
    ok = np.isfinite(z) & (z > 0)
    if ok.sum() < max(6, ok.size // 3):
        return None
    pts = np.column_stack([(us[ok] - k.cx) / k.fx * z[ok], (vs[ok] - k.cy) / k.fy * z[ok], z[ok]])
    c = pts.mean(axis=0)
    normal = np.linalg.svd(pts - c)[2][-1]
    ray = np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0])
    denom = float(normal @ ray)
    if abs(denom) < 1e-6:
        return None
    return ray * float(normal @ c) / denom
