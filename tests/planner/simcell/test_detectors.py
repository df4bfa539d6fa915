"""The rendered camera images behind the detector-noise figures: the spot's light against a
brute-force integral, 8-bit saturation, the board's geometry against the pinhole model."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.markers import CharucoSpec, detect_charuco
from planner.model.system import Intrinsics
from planner.model.transforms import axis_angle_to_matrix, make_T
from planner.simcell.detectors import (
    BOARD_COUNTS,
    frame,
    gated_frames,
    render_charuco,
    scene,
    spot_light,
    yuyv_roundtrip,
)

K = Intrinsics(848, 480, 430.0, 430.0, 424.0, 240.0)


@pytest.mark.parametrize("sigma", [0.3, 0.6, 2.0])
def test_spot_light_is_the_gaussian_averaged_over_each_pixel(sigma: float) -> None:
    """Against a brute-force average of point samples on a 41 x 41 grid per pixel."""
    centre, shape = (7.3, 5.8), (12, 15)
    light = spot_light((100.0, 10.0, 0.0), sigma, centre, shape)
    t = (np.arange(41) + 0.5) / 41 - 0.5  # sub-samples across one pixel
    vv = (np.arange(shape[0])[:, None] + t[None, :]).ravel()
    uu = (np.arange(shape[1])[:, None] + t[None, :]).ravel()
    g = np.exp(-((uu[None, :] - centre[0]) ** 2 + (vv[:, None] - centre[1]) ** 2) / (2 * sigma**2))
    brute = 100.0 * g.reshape(shape[0], 41, shape[1], 41).mean(axis=(1, 3))
    assert light[..., 0] == pytest.approx(brute, abs=2e-3 * 100.0)
    assert light[..., 1] == pytest.approx(0.1 * light[..., 0])
    # total light = peak x 2 pi sigma^2, whatever the size (on a frame holding all of it)
    whole = spot_light((100.0, 0.0, 0.0), sigma, (20.4, 19.7), (40, 40))[..., 0]
    assert whole.sum() == pytest.approx(100.0 * 2 * np.pi * sigma**2, rel=1e-6)


def test_a_wide_spot_centroid_is_its_centre() -> None:
    light = spot_light((50.0, 0.0, 0.0), 2.5, (20.37, 14.81), (30, 40))[..., 0]
    vv, uu = np.mgrid[0:30, 0:40]
    assert (light * uu).sum() / light.sum() == pytest.approx(20.37, abs=1e-4)
    assert (light * vv).sum() / light.sum() == pytest.approx(14.81, abs=1e-4)
    with pytest.raises(ValueError, match="sigma"):
        spot_light((1.0, 1.0, 1.0), 0.0)


def test_frames_are_8_bit_and_saturate() -> None:
    rng = np.random.default_rng(0)
    base = scene("board", estop=False, shape=(40, 40), spot=(20.0, 20.0))
    light = spot_light((900.0, 600.0, 500.0), 3.0, (20.0, 20.0), (40, 40))
    img = frame(base, light, rng)
    assert img.dtype == np.uint8
    assert np.all(img[18:23, 18:23] == 255)  # clipped in every channel
    quiet = frame(base, None, rng, noise=0.0)
    assert np.array_equal(quiet, np.round(base).astype(np.uint8))
    noisy = frame(base, None, rng).astype(float) - np.round(base)
    assert np.std(noisy) == pytest.approx(2.0, rel=0.05)  # NOISE_COUNTS
    on, off = gated_frames(base, light, rng, yuyv=True, frames=3)
    assert len(on) == len(off) == 3 and on[0].shape == (40, 40, 3)
    with pytest.raises(ValueError, match="board or skin"):
        scene("grass")


def test_yuyv_keeps_grey_and_shares_chroma_over_pairs() -> None:
    grey = np.full((2, 4, 3), 97, dtype=np.uint8)
    assert np.array_equal(yuyv_roundtrip(grey), grey)
    red = grey.copy()
    red[0, 0] = (250, 20, 20)  # one red pixel: its pair partner turns reddish too
    out = yuyv_roundtrip(red).astype(int)
    assert out[0, 1, 0] > out[0, 1, 1] + 20 and out[0, 0, 0] < 250


def test_board_render_puts_corners_where_the_pinhole_model_does() -> None:
    """Sharp and noise-free, the real detector's corners lie on the pinhole projections of
    the board's corners (independent of the renderer's homography): no offset (a pixel-centre
    convention error would shift all by 0.5 px), each within 0.2 px."""
    spec = CharucoSpec()
    c_T_b = make_T(axis_angle_to_matrix(np.array([0.2, -0.25, 0.3])), [-0.13, -0.07, 0.55])
    rgb, depth = render_charuco(spec, K, c_T_b)
    truth = spec.points() @ c_T_b[:3, :3].T + c_T_b[:3, 3]
    found = detect_charuco(rgb, depth, K, spec)
    seen = np.all(np.isfinite(found), axis=1)
    assert seen.sum() == len(truth)

    def uv(p: np.ndarray) -> np.ndarray:
        return np.column_stack([K.fx * p[:, 0] / p[:, 2] + K.cx, K.fy * p[:, 1] / p[:, 2] + K.cy])

    err = uv(found) - uv(truth)
    assert np.all(np.abs(err.mean(axis=0)) < 0.02) and np.max(np.abs(err)) < 0.2
    # depth: the board plane along each ray; a corner's pixel ray meets it at the corner
    u, v = np.round(uv(truth[:1])[0]).astype(int)
    ray = np.array([(u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0])
    n = c_T_b[:3, 2]
    assert depth[v, u] == pytest.approx(n @ c_T_b[:3, 3] / (n @ ray))
    assert {int(rgb.min()), int(rgb.max())} == {round(BOARD_COUNTS[0]), round(BOARD_COUNTS[1])}


def test_blur_and_noise_change_the_board_image() -> None:
    spec = CharucoSpec()
    c_T_b = make_T(np.eye(3), [-0.14, -0.1, 0.6])
    sharp, _ = render_charuco(spec, K, c_T_b)
    blurred, _ = render_charuco(spec, K, c_T_b, blur_px=1.0)
    # blur lowers the image gradient at the edges, keeps the mean
    grad = [np.abs(np.diff(im[..., 0].astype(float), axis=1)).max() for im in (sharp, blurred)]
    assert grad[1] < 0.7 * grad[0]
    assert blurred.mean() == pytest.approx(sharp.mean(), rel=0.01)
    with pytest.raises(ValueError, match="rng"):
        render_charuco(spec, K, c_T_b, noise=2.0)
