"""The one RealSense D435 measurement-noise model (simulated camera, calibration data, studies).

A feature seen at pixel (u, v) with depth z (m, along the optical axis) is measured as the
deprojection of a noisy pixel with a noisy depth, in the camera optical frame:

    p = ((u + du - cx) / fx, (v + dv - cy) / fy, 1) * (z + dz)
    du, dv ~ N(0, pixel_px^2),   dz ~ N(0, (depth_sigma(z, fx) / window)^2)

- ``depth_sigma(z, fx) = z^2 * SUBPIXEL / (fx * BASELINE)``: Intel's depth RMS error of one
  pixel (disparity RMS 0.08 px, baseline 50 mm): 2.8 mm at 0.87 m with fx = 430 px.
- ``window``: a feature's depth comes from a plane fitted to a window x window patch of
  depth pixels around it; with independent pixel errors the fitted depth at the centre has
  ``1 / window`` of the pixel RMS (window = 1: one raw depth pixel). This is optimistic: the
  D435's errors are spatially correlated over a few pixels.
- ``pixel_px``: the feature's image-position noise (spot centroid, chessboard corner).

Two presets, the ones the drivers' detectors work with: :data:`SPOT` (laser-spot centroid,
15 x 15 depth window, :mod:`drivers.camera.realsense`) and :data:`CORNER` (ChArUco corner,
sub-pixel corner, 9 x 9 depth window, :mod:`drivers.camera.markers`). Units: metres, pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from planner.model.transforms import Array

SUBPIXEL = 0.08  # px, D435 disparity RMS
BASELINE = 0.050  # m, D435 stereo baseline
FOCAL_PX = 430.0  # px, D435 depth focal length at 848 x 480
SPOT_PX = 0.05  # px, noise of the laser-spot centroid per image axis
SPOT_WINDOW = 15  # px, side of the depth window whose plane fit gives the spot depth
CORNER_PX = 0.1  # px, noise of a sub-pixel chessboard corner per image axis
CORNER_WINDOW = 9  # px, side of the depth window of a corner (drivers.camera.markers)


def depth_sigma(z: Any, fx: float) -> Any:
    """D435 depth RMS error (m) of one pixel at depth ``z`` (m) for focal length ``fx`` (px)."""
    return np.asarray(z) ** 2 * SUBPIXEL / (fx * BASELINE)


@dataclass(frozen=True)
class D435Noise:
    """D435 noise of one kind of feature (see the module docstring); ``outliers`` is the
    fraction of points displaced by 1-5 cm (a mismatched corner, a reflection)."""

    subpixel: float = SUBPIXEL
    baseline: float = BASELINE
    focal_px: float = FOCAL_PX
    lateral_px: float = CORNER_PX
    window: int = 1
    outliers: float = 0.0

    def with_focal(self, focal_px: float) -> D435Noise:
        """The same model for a camera of focal length ``focal_px`` (px)."""
        return replace(self, focal_px=float(focal_px))

    def depth_rms(self, z: Array) -> Array:
        """Depth noise RMS (m) of the feature at depth ``z`` (m), after the window fit."""
        return np.asarray(z * z * self.subpixel / (self.focal_px * self.baseline)) / self.window

    def apply(self, p_camera: Array, rng: np.random.Generator) -> Array:
        """Noisy copy of points ``(..., 3)`` in the camera frame (NaN rows stay NaN)."""
        p = np.array(p_camera, dtype=float)
        z = p[..., 2:3]
        dz = rng.normal(size=z.shape) * self.depth_rms(z)
        lateral = rng.normal(size=p.shape) * (z * self.lateral_px / self.focal_px)
        lateral[..., 2] = 0.0
        p = (p + lateral) * (1.0 + dz / z)
        if self.outliers > 0:
            flat = p.reshape(-1, 3)
            hit = rng.random(len(flat)) < self.outliers
            d = rng.normal(size=(int(hit.sum()), 3))
            d *= (rng.uniform(0.01, 0.05, len(d)) / np.linalg.norm(d, axis=1))[:, None]
            flat[hit] += d
        return p


SPOT = D435Noise(lateral_px=SPOT_PX, window=SPOT_WINDOW)
"""A laser spot: centroid 0.05 px, depth from a 15 x 15 plane fit (0.19 mm at 0.87 m)."""
CORNER = D435Noise(lateral_px=CORNER_PX, window=CORNER_WINDOW)
"""A ChArUco corner: 0.1 px, depth from a 9 x 9 plane fit (0.31 mm at 0.87 m)."""
