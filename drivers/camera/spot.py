"""Laser-spot detection by gating the laser: frames with the gate on minus frames with it off.

Pure functions of images (numpy, no device), so they are tested on rendered frames.

:func:`detect_gated_spot` takes colour (H x W x 3, uint8 RGB) or single-channel (H x W:
the IR stream, or any luminance) frames captured with the laser gate on and with it off:

1. signal image: the red channel of RGB frames (a 650 nm spot shows in red and, when it
   saturates, in every channel: its red channel is then flat-topped, not hollow as a
   "red minus green/blue" redness is), or the single channel itself; float, 0..255.
   With ``channel="luma"`` the BT.601 luminance instead: a YUYV (4:2:2) colour stream
   keeps luminance at full resolution but shares the chroma of two pixels, which smears
   and shifts the red of a 1-2 px spot.
2. difference ``D = mean(on) - mean(off)``: everything the laser does not light cancels
   (an e-stop button, skin, a red cable, the room light), only what the gate switched stays.
3. search window: ``radius`` px around the predicted pixel (the planner's predicted spot
   projected with the intrinsics), or the whole image without a prediction.
4. noise ``sigma``: the robust (MAD) spread of ``D`` in the window, floored at
   ``min_sigma``; the peak must exceed ``min_contrast`` and ``min_snr x sigma``, else no spot.
5. blob: the pixels connected to the peak above ``max(blob_fraction x peak, 3 sigma)``;
   centroid = sub-pixel, weighted by ``D`` minus that threshold (pixel centres are integers,
   as in OpenCV and librealsense).
6. confidence in [0, 1]: ``min(1, (snr - min_snr) / min_snr)`` times ``1 - second / peak``,
   where ``second`` is the highest peak of ``D`` outside the blob in the window (a second
   spot-like change makes the answer ambiguous); None (no spot) below ``min_confidence``.

Exposure: the difference only works when the spot does not change the camera's exposure
between the on and off frames: the RealSense source sets manual exposure and gain.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.model.transforms import Array

PREDICTION_TTL = 1.0  # s a predicted spot stays valid


@dataclass(frozen=True)
class SpotParams:
    """Detection thresholds (intensities in 0..255 units of the signal image, sizes in px)."""

    radius: float = 60.0
    min_contrast: float = 12.0
    min_snr: float = 8.0
    min_sigma: float = 0.5
    blob_fraction: float = 0.3
    min_confidence: float = 0.1
    channel: str = "red"  # "red" or "luma" (YUYV colour streams)


@dataclass(frozen=True)
class SpotDetection:
    """A detected spot: sub-pixel centre (u, v) in px, peak difference, noise, blob size."""

    u: float
    v: float
    peak: float
    sigma: float
    pixels: int
    confidence: float


def signal(frame: Array, channel: str = "red") -> Array:
    """The laser signal of one frame: red channel (or BT.601 luma) of RGB, or the single
    channel (float32)."""
    img: Any = np.asarray(frame)
    if img.ndim == 3 and channel == "luma":
        img = img.astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    elif img.ndim == 3:
        img = img[..., 0]
    if img.ndim != 2:
        raise ValueError(f"expected an H x W or H x W x 3 image, got shape {img.shape}")
    return img.astype(np.float32)


def difference(on: Sequence[Array], off: Sequence[Array], channel: str = "red") -> Array:
    """Mean of the gate-on signal minus mean of the gate-off signal (H x W, float32)."""
    if not on or not off:
        raise ValueError("need at least one frame with the gate on and one with it off")
    if channel not in ("red", "luma"):
        raise ValueError(f"channel must be red or luma, got {channel!r}")
    d = np.mean([signal(f, channel) for f in on], axis=0) - np.mean(
        [signal(f, channel) for f in off], axis=0
    )
    return np.asarray(d, dtype=np.float32)


def _window(shape: tuple[int, ...], uv: tuple[float, float] | None, radius: float) -> Array:
    h, w = shape[:2]
    mask = np.zeros((h, w), dtype=bool)
    if uv is None:
        mask[:] = True
        return mask
    u, v = uv
    if not (np.isfinite(u) and np.isfinite(v)):
        return mask
    vv, uu = np.ogrid[0:h, 0:w]
    mask[(uu - u) ** 2 + (vv - v) ** 2 <= radius**2] = True
    return mask


def detect_gated_spot(
    on: Sequence[Array],
    off: Sequence[Array],
    predicted_uv: tuple[float, float] | None = None,
    params: SpotParams | None = None,
) -> SpotDetection | None:
    """The laser spot in the on/off difference near ``predicted_uv`` (px), or None."""
    from scipy import ndimage

    params = params or SpotParams()
    d = difference(on, off, params.channel)
    win = _window(d.shape, predicted_uv, params.radius)
    if not win.any():
        return None
    vals = d[win]
    sigma = max(float(1.4826 * np.median(np.abs(vals - np.median(vals)))), params.min_sigma)
    dw = np.where(win, d, -np.inf)
    k = int(np.argmax(dw))
    v0, u0 = np.unravel_index(k, d.shape)
    peak = float(d[v0, u0])
    if peak < params.min_contrast or peak < params.min_snr * sigma:
        return None
    thr = max(params.blob_fraction * peak, 3.0 * sigma)
    labels, _ = ndimage.label(np.logical_and(d > thr, win))
    blob = labels == labels[v0, u0]
    vs, us = np.nonzero(blob)
    wgt = d[vs, us] - thr
    if float(wgt.sum()) <= 0:
        wgt = np.ones_like(wgt)
    u, v = float((us * wgt).sum() / wgt.sum()), float((vs * wgt).sum() / wgt.sum())
    grown = ndimage.binary_dilation(blob, iterations=2)
    rest = d[win & ~grown]
    second = float(rest.max()) if rest.size else 0.0
    snr = peak / sigma
    conf = min(1.0, (snr - params.min_snr) / params.min_snr) * (1.0 - max(second, 0.0) / peak)
    conf = float(np.clip(conf, 0.0, 1.0))
    if conf < params.min_confidence:
        return None
    return SpotDetection(u, v, peak, sigma, int(blob.sum()), conf)


def project(p_camera: Array, fx: float, fy: float, cx: float, cy: float) -> tuple[float, float]:
    """Pixel (u, v) of a point in the camera optical frame (m; z forward), pinhole model."""
    x, y, z = (float(c) for c in p_camera)
    if z <= 0:
        raise ValueError(f"point behind the camera (z = {z:.3f} m)")
    return fx * x / z + cx, fy * y / z + cy


class GateHistory:
    """Laser gate transitions (UNIX s) to classify frames by the gate state during their
    exposure: on, off, or None when it changed (or is unknown) in that interval."""

    def __init__(self, keep: float = 10.0) -> None:
        self.keep = keep
        self.events: list[tuple[float, bool]] = []  # (t, on), time ordered

    def record(self, on: bool, t: float) -> None:
        if self.events and t < self.events[-1][0]:
            return  # out of order: ignore
        if self.events and self.events[-1][1] == on:
            return
        self.events.append((t, on))
        while len(self.events) > 2 and self.events[1][0] < t - self.keep:
            self.events.pop(0)

    def state(self, t0: float, t1: float) -> bool | None:
        """The gate state over [t0, t1] (s), or None when it changed or was not known."""
        before = [on for t, on in self.events if t <= t0]
        if not before or any(t0 < t <= t1 for t, _ in self.events):
            return None
        return before[-1]
