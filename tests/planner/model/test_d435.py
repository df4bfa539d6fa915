"""The one D435 noise model: Intel's depth RMS formula, the window fit, the presets."""

from __future__ import annotations

import numpy as np
import pytest

from planner.calibration.simulate import DepthNoise
from planner.model import d435


def test_depth_sigma_is_intels_formula() -> None:
    # z^2 * subpixel / (fx * baseline): 0.87^2 * 0.08 / (430 * 0.05) = 2.816 mm
    assert d435.depth_sigma(0.87, 430.0) == pytest.approx(0.87**2 * 0.08 / 21.5)
    assert d435.depth_sigma(0.87, 430.0) == pytest.approx(2.8164e-3, rel=1e-4)


def test_presets_divide_the_pixel_rms_by_their_window() -> None:
    z = np.array(0.87)
    assert d435.SPOT.depth_rms(z) == pytest.approx(d435.depth_sigma(z, 430.0) / 15)
    assert d435.CORNER.depth_rms(z) == pytest.approx(d435.depth_sigma(z, 430.0) / 9)
    assert d435.CORNER.with_focal(860.0).depth_rms(z) == pytest.approx(
        d435.depth_sigma(z, 860.0) / 9
    )
    assert DepthNoise is d435.D435Noise  # calibration data use the same model


def test_noise_along_the_ray_and_across_it_has_the_stated_spread() -> None:
    """Depth error along the optical axis: depth_rms; lateral: pixel_px * z / fx."""
    rng = np.random.default_rng(0)
    p = np.tile([0.1, -0.05, 0.9], (40000, 1))
    out = d435.SPOT.apply(p, rng)
    dz = out[:, 2] - 0.9
    assert np.std(dz) == pytest.approx(float(d435.SPOT.depth_rms(np.array(0.9))), rel=0.03)
    # the pixel's ray direction after the noise: x/z, y/z spread = pixel_px / fx
    ux = out[:, 0] / out[:, 2] - 0.1 / 0.9
    assert np.std(ux) == pytest.approx(d435.SPOT_PX / 430.0, rel=0.03)
    assert np.allclose(np.mean(out, axis=0), p[0], atol=2e-5)


def test_nan_rows_stay_nan_and_silent_model_is_exact() -> None:
    rng = np.random.default_rng(1)
    p = np.array([[0.0, 0.0, 1.0], [np.nan, np.nan, np.nan]])
    out = d435.CORNER.apply(p, rng)
    assert np.all(np.isnan(out[1])) and np.all(np.isfinite(out[0]))
    silent = d435.D435Noise(subpixel=0.0, lateral_px=0.0)
    assert np.array_equal(silent.apply(p[:1], rng), p[:1])
