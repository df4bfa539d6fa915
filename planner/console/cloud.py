"""The live point cloud for the browser: decode, map to the world, colour, decimate.

``camera/points`` carries float32 rows in the camera optical frame (:mod:`schemas.points`);
the console maps them to the world with the scenario's ``world_T_camera``, keeps at most
``max_points`` of them (an even stride, so every frame keeps the same pixels and the picture
does not flicker) and colours them: the camera's own RGB when it sends one, else a ramp over
the depth along the camera's optical axis. A full D435 frame is ~400 k points; the default
budget of MAX_POINTS per frame keeps a frame near 0.3 MB on the websocket (float16
positions + RGB) and the browser's work small.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from planner.model.transforms import Array
from schemas.points import decode_points

#: default point budget per frame sent to the browser
MAX_POINTS = 30_000


class Cloud(NamedTuple):
    """A cloud ready to draw: ``points`` (M x 3 float32, world, m), ``colors`` (M x 3 uint8),
    the sender's time ``t`` (UNIX s) and frame ``seq``."""

    points: Array
    colors: Array
    t: float
    seq: int


def decimate(points: Array, max_points: int) -> NDArray[np.intp]:
    """Indices of an even stride through ``points`` keeping at most ``max_points`` rows."""
    n = len(points)
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    step = max(1, -(-n // max_points))  # ceil
    return np.arange(0, n, step)


def depth_colors(z: Array, lo: float | None = None, hi: float | None = None) -> Array:
    """A hue ramp over depths ``z`` (m) as M x 3 uint8: yellow (near, hue 50 deg) through
    green and cyan to blue (far, hue 230 deg), at constant saturation so every depth stands
    out from the grey scene; between ``lo`` and ``hi`` (default: the 2nd and 98th
    percentiles, so depth noise does not speckle the picture)."""
    z = np.asarray(z, dtype=float)
    if len(z) == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    lo = float(np.percentile(z, 2)) if lo is None else lo
    hi = float(np.percentile(z, 98)) if hi is None else hi
    s = np.clip((z - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    return hsv_colors(50.0 + 180.0 * s, 0.8, 0.95)


def hsv_colors(hue_deg: Array, sat: float, val: float) -> Array:
    """RGB (M x 3 uint8) of hues (deg) at one saturation and value (both in [0, 1])."""
    h = (np.asarray(hue_deg, dtype=float) % 360.0) / 60.0
    c = val * sat
    x = c * (1 - np.abs(h % 2 - 1))
    zero = np.zeros_like(h)
    sector = np.floor(h).astype(int) % 6
    rgb = np.select(
        [sector[:, None] == k for k in range(6)],
        [np.column_stack(t) for t in ((c + zero, x, zero), (x, c + zero, zero),
         (zero, c + zero, x), (zero, x, c + zero), (x, zero, c + zero), (c + zero, zero, x))],
    )  # fmt: skip
    return np.asarray(np.round(255 * (rgb + (val - c))), dtype=np.uint8)


def cloud_from_sample(
    payload: bytes, attachment: bytes, world_T_camera: Array, max_points: int = MAX_POINTS
) -> Cloud:
    """Decode a ``camera/points`` sample into a world-frame, decimated, coloured Cloud.

    Non-finite rows are dropped. InputError for a malformed sample (see
    :func:`schemas.points.decode_points`)."""
    data, meta = decode_points(payload, attachment)
    data = data[np.all(np.isfinite(data), axis=1)]
    data = data[decimate(data, max_points)] if len(data) else data
    xyz = data[:, :3].astype(float)
    world = xyz @ world_T_camera[:3, :3].T + world_T_camera[:3, 3]
    if data.shape[1] >= 6:
        colors = np.clip(255.0 * data[:, 3:6], 0, 255).astype(np.uint8)
    else:
        colors = depth_colors(xyz[:, 2])
    return Cloud(
        world.astype(np.float32), colors, float(meta.get("t", 0.0)), int(meta.get("seq", 0))
    )
