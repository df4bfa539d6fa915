"""Rendered camera images for the drivers' real detectors: gated laser-spot frames
(:func:`drivers.camera.spot.detect_gated_spot`) and ChArUco boards
(:func:`drivers.camera.markers.detect_charuco`), the figures behind the D435 model's lateral
noise (:data:`planner.model.d435.SPOT_PX`, :data:`~planner.model.d435.CORNER_PX`; measured by
:mod:`planner.simcell.detector_noise`, printed by ``beamrelay bench detectors``).

Images are 8-bit like the camera's streams: float intensities (counts, 0..255) plus
Gaussian sensor noise, rounded and clipped (a spot brighter than 255 saturates). Pixel
centres are at integer (u, v), as in OpenCV and librealsense; every light is integrated over
the pixel's area (a sub-pixel spot lights its pixel by its share, not by a point sample).

- Spot (:func:`spot_light`): a Gaussian of blur ``sigma`` (px) and peak ``amplitude`` (counts,
  per RGB channel) on a background (:func:`scene`: a grey board with a light gradient, a red
  e-stop button, or skin with a texture); :func:`gated_frames` gives the gate-on and gate-off
  frames the RealSense driver subtracts, optionally through a YUYV 4:2:2 stream
  (:func:`yuyv_roundtrip`).
- Board (:func:`render_charuco`): OpenCV's board image on its plane at a pose, rendered
  ``supersample`` times finer, blurred by a Gaussian PSF, averaged down to the camera's
  pixels, with sensor noise; plus the exact depth (m) of that plane along every pixel ray.

Frames: the camera optical frame (z forward, x right, y down); units px, counts, metres.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from planner.model.system import Intrinsics
from planner.model.transforms import Array

H, W = 480, 848  # px: the D435 colour stream the scenarios use (848 x 480)
SPOT = (431.3, 305.6)  # px, default true spot centre (sub-pixel)
ESTOP = (SPOT[0] - 426.0, SPOT[1])  # a red e-stop button 426 px to the left of it
#: counts RMS, temporal noise of an 8-bit colour pixel. Assumed: Intel's D400 datasheet gives
#: no noise figure for the colour (OV2740) stream; 2 counts is a moderate-gain CMOS sensor's
#: read + shot noise at mid-grey (a few electrons of read noise, ~1000 e- full well). Not
#: signal-dependent here.
NOISE_COUNTS = 2.0
#: frames per gate state: the RealSense driver subtracts the last 3 gate-on from the last 3
#: gate-off frames (``drivers.camera.realsense``, ``RealSenseCamera``'s gated difference)
FRAMES = 3
#: counts of the board's black and white squares under room light. Assumed: matte black
#: print reflects ~5 %, white paper ~80 %; with the driver's fixed exposure the white sits
#: below saturation
BOARD_COUNTS = (30.0, 200.0)
BACKGROUND_COUNTS = 128.0  # around the board: a mid-grey wall


def scene(
    kind: str = "board",
    estop: bool = True,
    shape: tuple[int, int] = (H, W),
    spot: tuple[float, float] = SPOT,
) -> Array:
    """Static background (H x W x 3 float RGB counts): a grey board with a light gradient
    (brighter to the right), a red e-stop button at :data:`ESTOP` (``estop``), and for
    ``kind="skin"`` a hand's skin with a texture, centred on ``spot`` (px)."""
    if kind not in ("board", "skin"):
        raise ValueError(f"background kind must be board or skin, got {kind!r}")
    vv, uu = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    img = np.empty((*shape, 3))
    img[:] = 110.0 + 40.0 * uu[..., None] / W
    if estop:
        img[np.hypot(uu - ESTOP[0], vv - ESTOP[1]) <= 28] = (230.0, 25.0, 20.0)
    if kind == "skin":
        skin = np.hypot((uu - spot[0]) / 140.0, (vv - spot[1]) / 90.0) <= 1.0
        tex = 8.0 * np.sin(uu / 3.0) * np.cos(vv / 4.0)
        img[skin] = np.stack([200 + tex, 140 + tex, 120 + tex], axis=-1)[skin]
    return img


def _pixel_share(centre: float, sigma: float, n: int) -> Array:
    """Mean over each pixel [i - 1/2, i + 1/2] of exp(-(x - centre)^2 / (2 sigma^2))."""
    from scipy.special import erf

    edges = (np.arange(n + 1) - 0.5 - centre) / (np.sqrt(2.0) * sigma)
    return np.asarray(np.sqrt(np.pi / 2.0) * sigma * np.diff(erf(edges)))


def spot_light(
    amplitude: tuple[float, float, float],
    sigma: float,
    centre: tuple[float, float] = SPOT,
    shape: tuple[int, int] = (H, W),
) -> Array:
    """The spot's light (H x W x 3 counts): a Gaussian of ``sigma`` (px) centred at
    ``centre`` (u, v px) with peak ``amplitude`` (counts per RGB channel), integrated over
    each pixel."""
    if sigma <= 0:
        raise ValueError(f"spot sigma must be > 0 px, got {sigma}")
    g = np.outer(_pixel_share(centre[1], sigma, shape[0]), _pixel_share(centre[0], sigma, shape[1]))
    return g[..., None] * np.asarray(amplitude, dtype=float)


def frame(
    base: Array, light: Array | None, rng: np.random.Generator, noise: float = NOISE_COUNTS
) -> Array:
    """One 8-bit frame: background + light + Gaussian noise (``noise`` counts RMS), rounded
    and clipped to 0..255 (saturation)."""
    img = base + (0.0 if light is None else light) + rng.normal(0.0, noise, base.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def yuyv_roundtrip(rgb: Array) -> Array:
    """RGB -> YUYV 4:2:2 (BT.601 full range, chroma averaged over pixel pairs) -> RGB."""
    f = rgb.astype(float)
    y = 0.299 * f[..., 0] + 0.587 * f[..., 1] + 0.114 * f[..., 2]
    cb = -0.168736 * f[..., 0] - 0.331264 * f[..., 1] + 0.5 * f[..., 2]
    cr = 0.5 * f[..., 0] - 0.418688 * f[..., 1] - 0.081312 * f[..., 2]
    cb = np.repeat(0.5 * (cb[:, 0::2] + cb[:, 1::2]), 2, axis=1)
    cr = np.repeat(0.5 * (cr[:, 0::2] + cr[:, 1::2]), 2, axis=1)
    y, cb, cr = np.round(y), np.round(cb), np.round(cr)  # 8-bit storage
    out = np.stack([y + 1.402 * cr, y - 0.344136 * cb - 0.714136 * cr, y + 1.772 * cb], -1)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def gated_frames(
    base: Array, light: Array, rng: np.random.Generator, yuyv: bool = False, frames: int = FRAMES
) -> tuple[list[Array], list[Array]]:
    """``frames`` gate-on frames (background + spot) and as many gate-off frames
    (background), each with its own sensor noise; through YUYV with ``yuyv``."""
    conv: Callable[[Array], Array] = yuyv_roundtrip if yuyv else (lambda x: x)
    on = [conv(frame(base, light, rng)) for _ in range(frames)]
    off = [conv(frame(base, None, rng)) for _ in range(frames)]
    return on, off


def render_charuco(
    spec: Any,
    k: Intrinsics,
    c_T_b: Array,
    blur_px: float = 0.0,
    noise: float = 0.0,
    rng: np.random.Generator | None = None,
    supersample: int = 4,
) -> tuple[Array, Array]:
    """A colour image (H x W x 3 uint8) and depth (H x W, m) of the ChArUco board ``spec``
    (:class:`drivers.camera.markers.CharucoSpec`) at pose ``c_T_b`` (board frame: OpenCV's,
    origin at a board corner, z into the board; camera optical frame). The board is warped
    ``supersample`` times finer than the camera's pixels, blurred by a Gaussian PSF of
    ``blur_px`` (camera px), averaged over each camera pixel, given ``noise`` counts RMS
    (``rng`` needed then) and stored in 8 bits. Depth: the board's plane, exact, everywhere."""
    import cv2

    s = int(supersample)
    ppm = 8000.0  # board image pixels per metre (0.125 mm: finer than a fine pixel at 0.3 m)
    w, h = spec.squares_x * spec.square, spec.squares_y * spec.square
    board = spec.board().generateImage((round(w * ppm), round(h * ppm)), marginSize=0)
    black, white = BOARD_COUNTS
    board = (black + (white - black) * (board.astype(np.float32) / 255.0)).astype(np.float32)
    # fine pixel i covers camera coordinate (i + 1/2) / s - 1/2 (pixel centres at integers)
    K = np.array([[s * k.fx, 0, s * (k.cx + 0.5) - 0.5], [0, s * k.fy, s * (k.cy + 0.5) - 0.5],
                  [0, 0, 1]])  # fmt: skip
    S = np.array([[1 / ppm, 0, 0.5 / ppm], [0, 1 / ppm, 0.5 / ppm], [0, 0, 1]])  # centres
    Hm = K @ np.column_stack([c_T_b[:3, 0], c_T_b[:3, 1], c_T_b[:3, 3]]) @ S
    fine = cv2.warpPerspective(board, Hm, (k.width * s, k.height * s), flags=cv2.INTER_LINEAR,
                               borderValue=BACKGROUND_COUNTS)  # fmt: skip
    if blur_px > 0:
        fine = cv2.GaussianBlur(fine, (0, 0), sigmaX=blur_px * s, sigmaY=blur_px * s)
    img = cv2.resize(fine, (k.width, k.height), interpolation=cv2.INTER_AREA).astype(float)
    if noise > 0:
        if rng is None:
            raise ValueError("sensor noise needs a random generator (rng)")
        img += rng.normal(0.0, noise, img.shape)
    gray = np.clip(np.round(img), 0, 255).astype(np.uint8)
    vv, uu = np.mgrid[0 : k.height, 0 : k.width].astype(float)
    rays = np.stack([(uu - k.cx) / k.fx, (vv - k.cy) / k.fy, np.ones_like(uu)], -1)
    n = c_T_b[:3, 2]
    depth = (n @ c_T_b[:3, 3]) / (rays @ n)
    return np.repeat(gray[..., None], 3, axis=2), depth
