"""The detectors' measured pixel noise: the interval against theory, the spot figure against
first-order error propagation, the board poses, and the D435 model's constants against a
fresh (small, seeded) measurement, so they cannot drift from the simulation."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.markers import CharucoSpec
from planner.model import d435
from planner.simcell import detector_noise as dn
from planner.simcell.detectors import FRAMES, NOISE_COUNTS, spot_light


def test_rms_ci_matches_the_normal_theory() -> None:
    """Errors N(0, s^2) per axis: mean square has standard error s^2 sqrt(2 / n) per axis;
    with two axes averaged per sample, s^2 sqrt(1 / n)."""
    rng = np.random.default_rng(0)
    n, s = 4000, 0.3
    e = rng.normal(0.0, s, (n, 2))
    m = dn.rms_ci(np.mean(e**2, axis=1), n, n)
    assert m.rms_px == pytest.approx(s, rel=0.03)
    half = 1.96 * s**2 / np.sqrt(n)
    assert m.ci95_px[0] == pytest.approx(np.sqrt(s**2 - half), rel=0.02)
    assert m.ci95_px[1] == pytest.approx(np.sqrt(s**2 + half), rel=0.02)
    assert m.ci95_px[0] < m.rms_px < m.ci95_px[1] and m.missed == 0
    assert np.isnan(dn.rms_ci(np.array([0.1]), 5, 1).rms_px)  # one sample: no interval


def _centroid_sigma_px(amplitude: float, sigma: float) -> float:
    """First-order propagation of the pixel noise through the detector's weighted centroid
    (independent of the detector's code): u = sum(u_i w_i) / sum(w_i), w_i = D_i - thr over
    the blob D > thr = 0.3 peak; dD_i has variance (noise^2 + 1/12 rounding) x (2 / FRAMES)
    (mean of FRAMES on minus mean of FRAMES off); the threshold's own noise moves every
    weight alike and drops out to first order."""
    c = (dn.CROP // 2, dn.CROP // 2)
    d = spot_light((amplitude, 0.0, 0.0), sigma, c, (dn.CROP, dn.CROP))[..., 0]
    blob = d > 0.3 * d.max()
    w = d[blob] - 0.3 * d.max()
    us = np.nonzero(blob)[1]
    u_bar = float((us * w).sum() / w.sum())
    var_d = (NOISE_COUNTS**2 + 1.0 / 12.0) * 2.0 / FRAMES
    return float(np.sqrt(var_d * ((us - u_bar) ** 2).sum()) / w.sum())


def test_a_wide_spot_error_is_the_propagated_pixel_noise() -> None:
    """A 3 px spot (no pixel locking) is only as precise as the pixel noise allows; a
    dimmer one, less."""
    for amplitude in (150.0, 60.0):
        cond = dn.SpotCondition("board", (amplitude, 0.0, 0.0), 3.0)
        m = dn.measure_spot_px(cond, samples=120, seed=2)
        expected = _centroid_sigma_px(amplitude, 3.0)
        assert m.missed == 0
        assert m.ci95_px[0] <= expected <= m.ci95_px[1], (amplitude, m, expected)


def test_random_board_poses_stay_in_the_image_at_their_depth() -> None:
    rng = np.random.default_rng(3)
    spec, k = CharucoSpec(), dn.PAPER_N1
    w, h = spec.squares_x * spec.square, spec.squares_y * spec.square
    for _ in range(30):
        T = dn.random_board_pose(rng, spec, k, 0.6)
        centre = T[:3, :3] @ [w / 2, h / 2, 0.0] + T[:3, 3]
        assert centre[2] == pytest.approx(0.6)
        tilt = np.degrees(np.arccos(np.clip(T[2, 2], -1.0, 1.0)))  # board z vs camera z
        assert tilt <= dn.MAX_TILT_DEG + 1e-9
    with pytest.raises(ValueError, match="fits"):
        dn.random_board_pose(rng, spec, k, 0.05)  # too close: never inside


def test_spot_model_constant_is_the_measured_bright_spot_on_a_board() -> None:
    """d435.SPOT_PX lies within a fresh measurement's 95 % CI (its condition, another seed)."""
    cond = dn.SPOT_CONDITIONS[dn.SPOT_MODEL_CONDITION]
    m = dn.measure_spot_px(cond, samples=80, seed=11)
    assert m.missed == 0
    assert m.ci95_px[0] <= d435.SPOT_PX <= m.ci95_px[1], m
    assert d435.SPOT.lateral_px == d435.SPOT_PX


def test_corner_model_constant_is_the_measured_blurred_board_at_0_9_m() -> None:
    """d435.CORNER_PX lies within a fresh measurement's 95 % CI (its condition, another seed)."""
    cond = dn.CORNER_CONDITIONS[dn.CORNER_MODEL_CONDITION]
    m = dn.measure_corner_px(cond, samples=16, seed=11)
    assert m.points > 100
    assert m.ci95_px[0] <= d435.CORNER_PX <= m.ci95_px[1], m
    assert d435.CORNER.lateral_px == d435.CORNER_PX
