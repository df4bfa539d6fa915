"""The one RealSense D435 measurement-noise model (simulated camera, calibration data, studies).

A feature seen at pixel (u, v) with depth z (m, along the optical axis) is measured as the
deprojection of a noisy pixel with a noisy depth, in the camera optical frame:

    p = ((u + du - cx) / fx, (v + dv - cy) / fy, 1) * (z_b + dz)
    du, dv ~ N(0, pixel_px^2),   dz ~ N(0, depth_rms(z)^2)

- ``depth_sigma(z, fx) = z^2 * SUBPIXEL / (fx * BASELINE)``: Intel's depth RMS error of one
  pixel (disparity RMS 0.08 px, baseline 50 mm): 2.8 mm at 0.87 m with fx = 430 px.
- ``window``: a feature's depth comes from a window x window patch of depth pixels around it
  (the corner: a plane fit, :mod:`drivers.camera.markers`; the spot: the median,
  :mod:`drivers.camera.realsense`). Its error is the pixel RMS times
  ``sqrt(window_correlation(window, correlation_px))``: with independent pixels
  (``correlation_px = 1``, the kind default) ``1 / window`` of it; with the D435's spatially
  correlated pixels (:data:`CENSUS_PX`, see :func:`window_correlation`) much less is averaged
  away. A median (``median``) keeps ``2 / pi`` of a mean's efficiency on the independent
  share of the noise.
- ``z_b``: the depth with the camera's own bias (``disparity_offset_px``, per camera; 0 by
  default): a stereo camera whose disparity is off by delta px measures
  ``z_b = z / (1 + z delta / (fx B))`` (:func:`biased_depth`); the datasheet bounds it
  (:data:`Z_ACCURACY`, :func:`max_disparity_offset`).
- ``pixel_px``: the feature's image-position noise (spot centroid, chessboard corner), as the
  drivers' detectors show it on rendered images (:mod:`planner.simcell.detector_noise`).

Two presets, the ones the drivers' detectors work with: :data:`SPOT` (laser-spot centroid,
15 x 15 depth window, :mod:`drivers.camera.realsense`) and :data:`CORNER` (ChArUco corner,
sub-pixel corner, 9 x 9 depth window, :mod:`drivers.camera.markers`); both with independent
pixels and no bias unless :meth:`D435Noise.with_errors` gives them the camera's
(:class:`DepthErrors`). Units: metres, pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from planner.model.transforms import Array

SUBPIXEL = 0.08  # px, D435 disparity RMS
BASELINE = 0.050  # m, D435 stereo baseline
FOCAL_PX = 430.0  # px, D435 depth focal length at 848 x 480
#: px, noise of the laser-spot centroid per image axis: ``beamrelay bench detectors`` (the
#: drivers' gated detector on rendered frames, 600 samples, seed 0), condition "bright spot on
#: board" (the paper_n1 camera, fx 430 px, at 0.87 m; an unsaturated spot of a 3 mm beam
#: blurred as a colour image is): 0.0267 px, 95 % CI [0.0257, 0.0277] (0.054 mm at 0.87 m)
SPOT_PX = 0.027
SPOT_WINDOW = 15  # px, side of the depth window whose plane fit gives the spot depth
#: px, noise of a ChArUco corner per image axis: ``beamrelay bench detectors`` (the drivers'
#: ChArUco detector on rendered boards, 120 random poses, seed 0), condition "corners at 0.9 m,
#: blurred" (the paper_n1 camera, fx 430 px; 0.5 px optical blur, 2 counts noise): 0.162 px,
#: 95 % CI [0.150, 0.173] (0.33 mm at 0.87 m; a third of the corners are not found there)
CORNER_PX = 0.16
CORNER_WINDOW = 9  # px, side of the depth window of a corner (drivers.camera.markers)
#: px, side of the D4's census matching window: librealsense's D400 advanced-mode presets
#: (``param-censususize`` / ``param-censusvsize`` = 9, ``STCensusRadius``). Two depth pixels
#: whose matching windows overlap share that fraction of their support, so their errors are
#: correlated: modelled as white noise box-filtered over CENSUS_PX x CENSUS_PX (correlation
#: (1 - |du|/9)(1 - |dv|/9), zero from 9 px apart; the D4's scanline optimisation may
#: correlate further along rows: not modelled)
CENSUS_PX = 9
#: Intel RealSense D400 Series datasheet (document 337029), D435 depth quality: absolute
#: (Z-) accuracy within 2 % of the distance at 2 m
Z_ACCURACY = 0.02
Z_ACCURACY_AT = 2.0  # m


def depth_sigma(z: Any, fx: float) -> Any:
    """D435 depth RMS error (m) of one pixel at depth ``z`` (m) for focal length ``fx`` (px)."""
    return np.asarray(z) ** 2 * SUBPIXEL / (fx * BASELINE)


def window_correlation(window: int, correlation_px: int) -> float:
    """The mean correlation over every pixel pair of a ``window`` x ``window`` patch, for
    pixel errors correlated as white noise box-filtered over ``correlation_px`` (1:
    independent): the variance of the patch's mean (= a centred plane fit's value at the
    centre) in units of one pixel's variance. Separable: (mean over pairs of
    ``max(0, 1 - |i - j| / correlation_px)``)^2."""
    i = np.arange(window)
    rho = np.clip(1.0 - np.abs(i[:, None] - i[None, :]) / max(correlation_px, 1), 0.0, None)
    return float(np.mean(rho) ** 2)


def biased_depth(z: Any, disparity_offset_px: float, fx: float, baseline: float = BASELINE) -> Any:
    """The depth (m) a stereo camera whose disparity is off by ``disparity_offset_px``
    measures for a true depth ``z`` (m): ``fx B / (fx B / z + delta)``."""
    z = np.asarray(z, dtype=float)
    return z / (1.0 + z * disparity_offset_px / (fx * baseline))


def max_disparity_offset(fx: float, baseline: float = BASELINE) -> float:
    """The largest disparity offset (px) whose depth error at :data:`Z_ACCURACY_AT` stays
    within the datasheet's :data:`Z_ACCURACY` either way (0.211 px at fx = 430 px; a negative
    offset reaches the bound: ``delta = fx B / z * a / (1 + a)``)."""
    a, z = Z_ACCURACY, Z_ACCURACY_AT
    return fx * baseline / z * a / (1.0 + a)


@dataclass(frozen=True)
class DepthErrors:
    """One physical camera's depth errors beyond the independent per-pixel noise:
    ``correlated`` (pixel errors correlated over :data:`CENSUS_PX`) and
    ``disparity_offset_px`` (its fixed depth bias, see :func:`biased_depth`)."""

    correlated: bool = False
    disparity_offset_px: float = 0.0

    @staticmethod
    def draw_offset(rng: np.random.Generator, fx: float) -> float:
        """A camera's disparity offset (px): uniform within the datasheet's bound (the
        datasheet gives a limit, no distribution)."""
        bound = max_disparity_offset(fx)
        return float(rng.uniform(-bound, bound))


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
    correlation_px: int = 1
    median: bool = False
    disparity_offset_px: float = 0.0

    def with_focal(self, focal_px: float) -> D435Noise:
        """The same model for a camera of focal length ``focal_px`` (px)."""
        return replace(self, focal_px=float(focal_px))

    def with_errors(self, errors: DepthErrors | None, median: bool = False) -> D435Noise:
        """The same feature seen by a camera with ``errors``: its bias, and with correlated
        pixels the real detector's window statistics (``median``: the window's median)."""
        if errors is None:
            return self
        corr = CENSUS_PX if errors.correlated else 1
        return replace(self, correlation_px=corr, median=median and errors.correlated,
                       disparity_offset_px=errors.disparity_offset_px)  # fmt: skip

    def window_variance(self) -> float:
        """The feature depth's variance in units of one pixel's (see the module docstring)."""
        v = window_correlation(self.window, self.correlation_px)
        if self.median:  # the independent share of the noise: var(median) = pi/2 var(mean)
            v += (np.pi / 2 - 1.0) / self.window**2
        return v

    def depth_rms(self, z: Array) -> Array:
        """Depth noise RMS (m) of the feature at depth ``z`` (m), after the window fit."""
        pixel = np.asarray(z * z * self.subpixel / (self.focal_px * self.baseline))
        return pixel * float(np.sqrt(self.window_variance()))

    def apply(self, p_camera: Array, rng: np.random.Generator) -> Array:
        """Noisy copy of points ``(..., 3)`` in the camera frame (NaN rows stay NaN)."""
        p = np.array(p_camera, dtype=float)
        z = p[..., 2:3]
        dz = rng.normal(size=z.shape) * self.depth_rms(z)
        lateral = rng.normal(size=p.shape) * (z * self.lateral_px / self.focal_px)
        lateral[..., 2] = 0.0
        if self.disparity_offset_px:
            dz = dz + biased_depth(z, self.disparity_offset_px, self.focal_px, self.baseline) - z
        p = (p + lateral) * (1.0 + dz / z)
        if self.outliers > 0:
            flat = p.reshape(-1, 3)
            hit = rng.random(len(flat)) < self.outliers
            d = rng.normal(size=(int(hit.sum()), 3))
            d *= (rng.uniform(0.01, 0.05, len(d)) / np.linalg.norm(d, axis=1))[:, None]
            flat[hit] += d
        return p


SPOT = D435Noise(lateral_px=SPOT_PX, window=SPOT_WINDOW)
"""A laser spot: centroid :data:`SPOT_PX`, depth from a 15 x 15 plane fit (0.19 mm at 0.87 m)."""
CORNER = D435Noise(lateral_px=CORNER_PX, window=CORNER_WINDOW)
"""A ChArUco corner: :data:`CORNER_PX`, depth from a 9 x 9 plane fit (0.31 mm at 0.87 m)."""
