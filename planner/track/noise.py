"""Measurement noise of a tracked point seen by a D435 (the simulated camera's spot model).

A marker (or the laser spot) is found at a pixel centroid with noise ``centroid_px`` per
image axis, and its depth is the depth of a plane fitted to the ``window_px`` x
``window_px`` pixels around it: the D435 depth RMS ``z^2 subpixel / (fx baseline)``
divided by ``window_px`` (the sim camera's spot detection, :mod:`drivers.camera.sim`). In
the camera optical frame a point ``p = z r`` with ``r = (x/z, y/z, 1)`` gets

    dp = (z / fx) (du e_x + dv e_y) + dz r,   du, dv ~ N(0, centroid_px^2), dz ~ N(0, s_z^2)

so its covariance is ``(z centroid_px / fx)^2 (e_x e_x' + e_y e_y') + s_z^2 r r'`` (m^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.calibration.simulate import DepthNoise
from planner.model import d435
from planner.model.transforms import Array

#: px, noise of a centroid per image axis: the D435 model's spot (as the sim camera's)
CENTROID_PX = d435.SPOT_PX
#: px, side of the window whose plane fit gives the depth: the D435 model's spot window
WINDOW_PX = d435.SPOT_WINDOW


@dataclass(frozen=True)
class MarkerNoise:
    """The D435 noise of one tracked point (see the module docstring); ``fx`` in px."""

    fx: float = 430.0
    centroid_px: float = CENTROID_PX
    window_px: int = WINDOW_PX
    subpixel: float = DepthNoise.subpixel
    baseline: float = DepthNoise.baseline

    def depth_sigma(self, z: float) -> float:
        """RMS (m) of the fitted depth at ``z`` m."""
        return z * z * self.subpixel / (self.fx * self.baseline) / self.window_px

    def covariance_camera(self, p_camera: Array) -> Array:
        """3x3 covariance (m^2) of a point ``p_camera`` (camera optical frame, m, z > 0)."""
        p = np.asarray(p_camera, dtype=float)
        z = float(p[2])
        r = p / z
        lateral = (z * self.centroid_px / self.fx) ** 2
        return lateral * np.diag([1.0, 1.0, 0.0]) + self.depth_sigma(z) ** 2 * np.outer(r, r)

    def covariance_world(self, p_world: Array, world_T_camera: Array) -> Array:
        """3x3 covariance (m^2, world frame) of a world point seen by the camera at
        ``world_T_camera``."""
        R, c = world_T_camera[:3, :3], world_T_camera[:3, 3]
        p_c = R.T @ (np.asarray(p_world, dtype=float) - c)
        return R @ self.covariance_camera(p_c) @ R.T

    def sample_camera(self, p_camera: Array, rng: np.random.Generator) -> Array:
        """A noisy measurement of ``p_camera`` (m, camera frame), drawn as the sim camera
        draws its spot: centroid pixel noise, then the fitted depth's noise along the ray."""
        p = np.asarray(p_camera, dtype=float)
        z = float(p[2])
        du, dv = self.centroid_px * rng.standard_normal(2)
        zn = z + self.depth_sigma(z) * rng.standard_normal()
        ray = np.array([p[0] / z + du / self.fx, p[1] / z + dv / self.fx, 1.0])
        return ray * zn
