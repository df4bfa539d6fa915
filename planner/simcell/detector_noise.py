"""The image-position noise of the drivers' real detectors, measured on rendered images
(:mod:`planner.simcell.detectors`): the source of the D435 model's lateral noise
(:data:`planner.model.d435.SPOT_PX`, :data:`~planner.model.d435.CORNER_PX`), printed by
``beamrelay bench detectors``.

- :func:`measure_spot_px`: per sample a spot at a random sub-pixel position (uniform over a
  pixel), gated frames (:data:`~planner.simcell.detectors.FRAMES` on, as many off) with
  their own sensor noise, :func:`drivers.camera.spot.detect_gated_spot` with a prediction a
  few px off (N(0, 5 px) per axis, as the planner's is). Frames are 160 x 160 px crops around
  the spot: the detector looks only within its 60 px window, so the rest of an 848 x 480
  frame does not change its answer.
- :func:`measure_corner_px`: per sample a ChArUco board (the drivers' default
  :class:`drivers.camera.markers.CharucoSpec`) at a random pose: its centre at the condition's
  depth, anywhere the whole board stays in the image, tilted up to 30 deg about a random
  in-plane axis, turned by any angle in its plane;
  :func:`drivers.camera.markers.detect_charuco` on the rendered image and exact depth; each
  corner found is projected back to its pixel (the exact depth plane makes that its detected
  pixel) and compared with the true corner's projection.

Error = detected - true pixel, per image axis. RMS per axis = sqrt(mean over samples of x),
x = a sample's mean squared error over its axes (and its corners); 95 % CI: the normal
interval on mean(x) (central limit over independent samples), square-rooted. A sample with
nothing detected is counted in ``missed`` and adds no error. Units: px (camera pixels of
:data:`PAPER_N1`), metres, counts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from drivers.camera.markers import CharucoSpec, detect_charuco
from drivers.camera.spot import SpotParams, detect_gated_spot
from planner.model.system import Intrinsics
from planner.model.transforms import Array, axis_angle_to_matrix, make_T
from planner.simcell.detectors import NOISE_COUNTS, gated_frames, render_charuco, scene, spot_light

#: the camera of ``scenarios/paper_n1.yaml`` (848 x 480, fx = fy = 430 px): the model's
#: pixels are this camera's (the simulated camera applies them at the scenario's focal length)
PAPER_N1 = Intrinsics(848, 480, 430.0, 430.0, 424.0, 240.0)
DISTANCE_M = 0.87  # m: the paper_n1 camera to its targets and board (the scenario's layout)
#: m, the laser's 1/e^2 beam diameter at the target. Assumed: the repository holds no laser
#: datasheet; a collimated 650 nm laser-diode module gives 2-4 mm
BEAM_DIAMETER_M = 0.003
#: px, optical blur (Gaussian PSF sigma) of a D435 colour image at 848 x 480. Assumed:
#: diffraction at f/2.0 and 650 nm is sigma = 0.42 lambda N = 0.55 um = 0.4 of the OV2740's
#: 1.4 um pixels; with ~1 sensor px more from Bayer demosaicing and the fixed-focus lens
#: (no datasheet MTF) about 1.1 sensor px, / 2.26 from the 1920-px sensor to 848 px = 0.5 px
BLUR_PX = 0.5
CROP = 160  # px, side of a spot crop (holds the detector's 60 px window; even, for YUYV pairs)
PREDICTION_PX = 5.0  # px RMS per axis, the planner's predicted spot off the true one
MAX_TILT_DEG = 30.0  # deg, a board's largest tilt from facing the camera


def spot_sigma_px(beam_m: float, z_m: float, fx: float, blur_px: float) -> float:
    """Image sigma (px) of a laser spot: the beam's 1/e^2 diameter ``beam_m`` (intensity
    sigma = diameter / 4) seen at depth ``z_m`` with focal length ``fx`` (px), combined in
    quadrature with the optics' blur ``blur_px``."""
    return float(np.hypot(beam_m / 4.0 * fx / z_m, blur_px))


@dataclass(frozen=True)
class SpotCondition:
    """A spot case: background (``board`` or ``skin``), peak amplitude (counts, RGB), image
    sigma (px) and whether the colour stream is YUYV (the detector then uses luma)."""

    background: str
    amplitude: tuple[float, float, float]
    sigma_px: float
    yuyv: bool = False


@dataclass(frozen=True)
class CornerCondition:
    """A board case: depth of its centre (m) and optical blur (px)."""

    distance_m: float
    blur_px: float


_BOARD_SPOT = spot_sigma_px(BEAM_DIAMETER_M, DISTANCE_M, PAPER_N1.fx, BLUR_PX)  # 0.62 px
SPOT_CONDITIONS = {
    # the experiments' case: the paper_n1 camera at 0.87 m, a bright unsaturated spot
    # (120 counts of red over a ~130-count board, assumed) blurred as a colour image is
    "bright spot on board": SpotCondition("board", (120.0, 15.0, 10.0), _BOARD_SPOT),
    # red light spreads several mm in skin (subsurface scattering, assumed 4 px = 8 mm)
    "low-contrast spot on skin": SpotCondition("skin", (25.0, 6.0, 4.0), 4.0),
    # the board's spot overexposed (its core clips at 255 in every channel: white)
    "saturated spot": SpotCondition("board", (900.0, 600.0, 500.0), _BOARD_SPOT),
    # the beam alone (a sharp lens), through a YUYV 4:2:2 stream
    "small spot after YUYV": SpotCondition(
        "board",
        (140.0, 10.0, 10.0),
        spot_sigma_px(BEAM_DIAMETER_M, DISTANCE_M, PAPER_N1.fx, 0.0),
        yuyv=True,
    ),
}
SPOT_MODEL_CONDITION = "bright spot on board"
CORNER_CONDITIONS = {
    "corners at 0.6 m, sharp": CornerCondition(0.6, 0.0),
    "corners at 0.6 m, blurred": CornerCondition(0.6, BLUR_PX),
    "corners at 0.9 m, sharp": CornerCondition(0.9, 0.0),
    "corners at 0.9 m, blurred": CornerCondition(0.9, BLUR_PX),
}
CORNER_MODEL_CONDITION = "corners at 0.9 m, blurred"


class Measured(NamedTuple):
    """A detector's per-axis RMS error (px) with its 95 % CI (px), the samples measured,
    those with nothing detected (``missed``) and the errors pooled (``points``: spots or
    corners)."""

    rms_px: float
    ci95_px: tuple[float, float]
    samples: int
    missed: int
    points: int


def rms_ci(x: Array, samples: int, points: int) -> Measured:
    """:class:`Measured` from ``x``, one mean squared error (px^2) per sample that detected
    something (see the module docstring for the interval)."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return Measured(
            float("nan"), (float("nan"), float("nan")), samples, samples - len(x), points
        )
    m, se = float(np.mean(x)), float(np.std(x, ddof=1) / np.sqrt(len(x)))
    lo, hi = np.sqrt(max(m - 1.96 * se, 0.0)), np.sqrt(m + 1.96 * se)
    return Measured(float(np.sqrt(m)), (float(lo), float(hi)), samples, samples - len(x), points)


def measure_spot_px(cond: SpotCondition, samples: int = 200, seed: int = 0) -> Measured:
    """The gated spot detector's per-axis error (px) under ``cond`` (see the module)."""

    rng = np.random.default_rng(seed)
    params = SpotParams(channel="luma" if cond.yuyv else "red")
    x = []
    for _ in range(samples):
        true = (CROP // 2 + rng.uniform(-0.5, 0.5), CROP // 2 + rng.uniform(-0.5, 0.5))
        base = scene(cond.background, estop=False, shape=(CROP, CROP), spot=true)
        light = spot_light(cond.amplitude, cond.sigma_px, true, (CROP, CROP))
        on, off = gated_frames(base, light, rng, cond.yuyv)
        guess = (true[0] + rng.normal(0, PREDICTION_PX), true[1] + rng.normal(0, PREDICTION_PX))
        found = detect_gated_spot(on, off, guess, params)
        if found is not None:
            x.append(((found.u - true[0]) ** 2 + (found.v - true[1]) ** 2) / 2.0)
    return rms_ci(np.array(x), samples, len(x))


def _uv(p: Array, k: Intrinsics) -> Array:
    return np.column_stack([k.fx * p[:, 0] / p[:, 2] + k.cx, k.fy * p[:, 1] / p[:, 2] + k.cy])


def random_board_pose(
    rng: np.random.Generator, spec: object, k: Intrinsics, distance_m: float
) -> Array:
    """camera_T_board (4 x 4, m): the board's centre at depth ``distance_m``, the whole
    board at least 10 px inside the image, tilted up to :data:`MAX_TILT_DEG`, any in-plane
    angle (board frame: OpenCV's, z away from the camera)."""
    w = spec.squares_x * spec.square  # type: ignore[attr-defined]
    h = spec.squares_y * spec.square  # type: ignore[attr-defined]
    corners = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]], dtype=float)
    for _ in range(1000):
        axis = rng.normal(size=2)
        tilt = np.radians(MAX_TILT_DEG) * np.sqrt(rng.uniform())  # uniform over the cap
        turn = axis_angle_to_matrix(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)]))
        R = axis_angle_to_matrix(np.append(axis / np.linalg.norm(axis) * tilt, 0.0)) @ turn
        u, v = rng.uniform(0, k.width), rng.uniform(0, k.height)
        centre = np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0]) * distance_m
        T = make_T(R, centre - R @ np.array([w / 2, h / 2, 0.0]))
        uv = _uv(corners @ T[:3, :3].T + T[:3, 3], k)
        if np.all((uv >= 10) & (uv <= np.array([k.width, k.height]) - 11)):
            return T
    raise ValueError(f"no board pose at {distance_m} m fits in a {k.width} x {k.height} image")


def measure_corner_px(
    cond: CornerCondition, samples: int = 40, seed: int = 0, k: Intrinsics = PAPER_N1
) -> Measured:
    """The ChArUco detector's per-axis corner error (px) under ``cond`` (see the module)."""

    rng = np.random.default_rng(seed)
    spec = CharucoSpec()
    x, points = [], 0
    for _ in range(samples):
        c_T_b = random_board_pose(rng, spec, k, cond.distance_m)
        rgb, depth = render_charuco(spec, k, c_T_b, cond.blur_px, NOISE_COUNTS, rng)
        found = detect_charuco(rgb, depth, k, spec)
        seen = np.all(np.isfinite(found), axis=1)
        if not seen.any():
            continue
        truth = spec.points() @ c_T_b[:3, :3].T + c_T_b[:3, 3]
        err = _uv(found[seen], k) - _uv(truth[seen], k)
        x.append(float(np.mean(err**2)))
        points += int(seen.sum())
    return rms_ci(np.array(x), samples, points)
