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


# --- spatially correlated pixels and the camera's bias ----------------------------------------
def _box_field(rng: np.random.Generator, shape: tuple[int, int], m: int) -> np.ndarray:
    """Unit-variance white noise averaged over m x m boxes (an independent construction:
    a 2D convolution with a box kernel, scaled by m)."""
    from scipy.signal import fftconvolve

    white = rng.standard_normal((shape[0] + m - 1, shape[1] + m - 1))
    return fftconvolve(white, np.ones((m, m)), mode="valid") / m


@pytest.mark.parametrize(("window", "corr"), [(9, 1), (9, 9), (15, 9), (15, 4)])
def test_window_correlation_is_the_mean_over_every_pixel_pair(window: int, corr: int) -> None:
    u, v = np.meshgrid(np.arange(window), np.arange(window))
    du = np.abs(u.ravel()[:, None] - u.ravel()[None, :])
    dv = np.abs(v.ravel()[:, None] - v.ravel()[None, :])
    rho = np.clip(1 - du / corr, 0, None) * np.clip(1 - dv / corr, 0, None)
    assert d435.window_correlation(window, corr) == pytest.approx(rho.mean(), rel=1e-12)


@pytest.mark.parametrize("window", [9, 15])
def test_a_plane_fit_on_correlated_pixels_keeps_the_modelled_error(window: int) -> None:
    """Monte Carlo: the centre value of a least-squares plane over the window, on fields
    correlated over the census window, has the std the model gives."""
    rng = np.random.default_rng(7)
    r = window // 2
    u, v = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1))
    A = np.column_stack([np.ones(window * window), u.ravel(), v.ravel()])
    fields = _box_field(rng, (window, 6000 * window), d435.CENSUS_PX)
    patches = fields.reshape(window, 6000, window).transpose(1, 0, 2).reshape(6000, -1)
    centre = np.linalg.lstsq(A, patches.T, rcond=None)[0][0]
    expected = np.sqrt(d435.window_correlation(window, d435.CENSUS_PX))
    assert np.std(centre) == pytest.approx(expected, rel=0.05)
    # the box field's own neighbour correlation is the triangle the model assumes
    f = _box_field(rng, (200, 2000), d435.CENSUS_PX)
    for lag in (1, 4, 8, 9):
        c = np.mean(f[:, :-lag] * f[:, lag:])
        assert c == pytest.approx(max(0.0, 1 - lag / d435.CENSUS_PX), abs=0.02)


def test_the_spot_median_on_correlated_pixels_has_the_modelled_error() -> None:
    rng = np.random.default_rng(8)
    w = d435.SPOT_WINDOW
    fields = _box_field(rng, (w, 6000 * w), d435.CENSUS_PX)
    patches = fields.reshape(w, 6000, w).transpose(1, 0, 2).reshape(6000, -1)
    noise = d435.SPOT.with_errors(d435.DepthErrors(correlated=True), median=True)
    assert np.std(np.median(patches, axis=1)) == pytest.approx(
        np.sqrt(noise.window_variance()), rel=0.08
    )


def test_the_datasheet_bound_is_two_percent_at_two_metres() -> None:
    fx = 430.0
    bound = d435.max_disparity_offset(fx)
    # disparity of a point 2 m away, shifted by the bound, back to depth by triangulation
    disparity = fx * d435.BASELINE / 2.0
    z = [fx * d435.BASELINE / (disparity + s * bound) for s in (1.0, -1.0)]
    errors = [abs(zi - 2.0) / 2.0 for zi in z]
    assert max(errors) == pytest.approx(0.02, rel=1e-9) and min(errors) < 0.02
    for zi, s in zip(z, (1.0, -1.0), strict=True):
        assert d435.biased_depth(2.0, s * bound, fx) == pytest.approx(zi, rel=1e-12)
    draws = [d435.DepthErrors.draw_offset(np.random.default_rng(s), fx) for s in range(2000)]
    assert max(np.abs(draws)) <= bound and np.std(draws) == pytest.approx(
        bound / np.sqrt(3), rel=0.05
    )


def test_features_carry_the_bias_and_the_correlated_window_error() -> None:
    rng = np.random.default_rng(2)
    errors = d435.DepthErrors(correlated=True, disparity_offset_px=0.1)
    noise = d435.CORNER.with_errors(errors)
    z0 = 0.87
    out = noise.apply(np.tile([0.02, 0.01, z0], (40000, 1)), rng)
    bias = d435.biased_depth(z0, 0.1, d435.FOCAL_PX) - z0
    pixel = d435.depth_sigma(z0, d435.FOCAL_PX)
    assert np.mean(out[:, 2] - z0) == pytest.approx(bias, abs=3 * pixel / 200)
    expected = pixel * np.sqrt(d435.window_correlation(d435.CORNER_WINDOW, d435.CENSUS_PX))
    assert np.std(out[:, 2]) == pytest.approx(expected, rel=0.03)
    assert d435.CORNER.with_errors(None) == d435.CORNER
