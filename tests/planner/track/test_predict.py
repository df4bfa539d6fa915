"""Predictors against known motions with the D435 marker noise: bounds from the noise."""

from __future__ import annotations

import numpy as np
import pytest

from planner.model.motion import ObjectMotion
from planner.model.transforms import quat_to_matrix
from planner.track.noise import MarkerNoise
from planner.track.predict import NIS_GATE, ConstantVelocity, KalmanCV, accel_sigma_for

RATE = 30.0  # Hz, camera frames
LEAD = 0.05  # s, from capture to the time the command takes effect
P0 = np.array([-0.492, -0.55, -0.06])  # m, the breathing phantom's mark
CAMERA = np.eye(4)
CAMERA[:3, :3] = quat_to_matrix([-0.816822211, 0.351473396, -0.180812777, 0.420207886])
CAMERA[:3, 3] = [-1.0, -1.0, 0.5]
NOISE = MarkerNoise(fx=430.0)


def measure(motion: ObjectMotion, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capture times, true points and noisy measurements (world) of ``n`` frames."""
    rng = np.random.default_rng(seed)
    t = 0.01 + np.arange(n) / RATE
    truth = P0 + motion.offset(t)
    R, c = CAMERA[:3, :3], CAMERA[:3, 3]
    z = np.array([R @ NOISE.sample_camera(R.T @ (p - c), rng) + c for p in truth])
    return t, truth, z


def run(pred, motion, n=300, seed=0, lead=LEAD):
    t, truth, z = measure(motion, n, seed)
    out = []
    for k in range(n):
        pred.update(t[k], z[k], NOISE.covariance_world(z[k], CAMERA))
        p = pred.predict(t[k] + lead)
        out.append((p, P0 + motion.offset(t[k] + lead), pred.predict(t[k]).p, truth[k], z[k]))
    return out


def test_noise_model_samples_match_its_covariance() -> None:
    rng = np.random.default_rng(1)
    p_c = np.array([0.05, -0.03, 0.87])
    draws = np.array([NOISE.sample_camera(p_c, rng) for _ in range(20000)]) - p_c
    cov = NOISE.covariance_camera(p_c)
    np.testing.assert_allclose(np.cov(draws.T), cov, atol=0.05 * np.abs(cov).max())
    # the depth RMS is the sim camera's spot depth model: D435 RMS / window
    from drivers.camera.sim import SIGMA_PX, SPOT_WINDOW, depth_sigma

    assert NOISE.depth_sigma(0.87) == pytest.approx(depth_sigma(0.87, 430.0) / SPOT_WINDOW)
    assert (NOISE.centroid_px, NOISE.window_px) == (SIGMA_PX, SPOT_WINDOW)


def test_constant_velocity_is_exact_on_a_noise_free_line() -> None:
    cv = ConstantVelocity()
    v = np.array([0.02, -0.01, 0.005])
    for k in range(3):
        cv.update(k / RATE, P0 + v * k / RATE, np.zeros((3, 3)))
    p = cv.predict(2 / RATE + LEAD)
    np.testing.assert_allclose(p.p, P0 + v * (2 / RATE + LEAD), atol=1e-15)
    np.testing.assert_allclose(p.v, v, atol=1e-12)


def test_constant_velocity_error_matches_its_covariance() -> None:
    """On a line, the CV prediction's error is the propagated measurement noise: its
    covariance (1 + k)^2 R2 + k^2 R1 with k = lead / frame period."""
    motion = ObjectMotion.linear([0.02, 0.0, 0.0], 5.0)
    err = np.vstack([
        [p.p - true for p, true, *_ in run(ConstantVelocity(), motion, n=140, seed=s)[1:]]
        for s in range(15)
    ])  # fmt: skip
    k = LEAD * RATE
    expected = (1 + k) ** 2 + k**2  # times R (the same R at every frame, to < 1 %)
    R = NOISE.covariance_world(P0, CAMERA)
    assert np.mean(np.sum(err**2, axis=1)) == pytest.approx(expected * np.trace(R), rel=0.1)


@pytest.mark.parametrize(
    "motion",
    [ObjectMotion.linear([0.02, 0.0, 0.0], 5.0), ObjectMotion.sine([0, 0, 1], 0.005, 0.25)],
    ids=["linear-20mm/s", "sine-5mm-0.25Hz"],
)
def test_kalman_beats_the_raw_measurements(motion: ObjectMotion) -> None:
    res = run(KalmanCV(), motion, n=150)[30:]  # after one second of convergence
    filtered = np.array([est - true for _, _, est, true, _ in res])
    raw = np.array([z - true for *_, true, z in res])
    rms_f = np.sqrt(np.mean(np.sum(filtered**2, axis=1)))
    rms_raw = np.sqrt(np.mean(np.sum(raw**2, axis=1)))
    assert rms_f < 0.7 * rms_raw, (rms_f, rms_raw)


@pytest.mark.parametrize(
    "motion",
    [ObjectMotion.linear([0.02, 0.0, 0.0], 5.0), ObjectMotion.sine([0, 0, 1], 0.005, 0.25)],
    ids=["linear-20mm/s", "sine-5mm-0.25Hz"],
)
def test_kalman_prediction_error_within_its_bound(motion: ObjectMotion) -> None:
    """The error of the prediction ``LEAD`` s ahead stays within the filter's own 3-sigma
    plus the motion's unmodelled acceleration over the horizon, a (lead + 1/rate)^2 / 2,
    at >= 99 % of frames (over 8 runs of 5 s)."""
    a = motion.peak_acceleration
    inside = []
    for seed in range(8):
        res = run(KalmanCV(), motion, n=150, seed=seed)[30:]
        bound = np.array([3 * p.sigma + a * (LEAD + 1 / RATE) ** 2 / 2 for p, *_ in res])
        err = np.array([np.linalg.norm(p.p - true) for p, true, *_ in res])
        inside += list(err <= bound)
    assert np.mean(inside) >= 0.99


def test_kalman_is_not_overconfident_on_a_line() -> None:
    """Normalised estimation error squared (3 dof): its mean is at most 3 (plus the
    sampling spread) when the motion is within the model."""
    motion = ObjectMotion.linear([0.02, 0.01, 0.0], 5.0)
    nees = [
        (e := p.p - true) @ np.linalg.solve(p.cov, e)
        for seed in range(6)
        for p, true, *_ in run(KalmanCV(), motion, n=150, seed=seed)[30:]
    ]
    assert np.mean(nees) < 3.6


def test_kalman_restarts_on_a_turnaround_and_reconverges() -> None:
    """A linear motion turning back (20 mm/s -> -20 mm/s) is a manoeuvre: the innovation
    exceeds the gate, the reported uncertainty grows, and within 15 frames the prediction
    is back within its bound."""
    motion = ObjectMotion.linear([0.02, 0.0, 0.0], 2.0)
    kf = KalmanCV()
    res = run(kf, motion, n=120)  # 4 s: the turnaround at 2 s = frame 60
    assert kf.manoeuvres >= 1
    sig = np.array([p.sigma for p, *_ in res])
    assert sig[60:66].max() > 3 * sig[50:58].mean()
    err = np.array([np.linalg.norm(p.p - true) for p, true, *_ in res])
    assert np.all(err[75:115] <= 3 * sig[75:115] + 2e-4)


def test_accel_sigma_is_the_sine_of_that_scale() -> None:
    # 5 mm at 0.25 Hz: peak speed 7.85 mm/s, peak acceleration 12.3 mm/s^2
    m = ObjectMotion.sine([0, 0, 1], 0.005, 0.25)
    assert accel_sigma_for(m.peak_speed, m.period) * np.sqrt(2) == pytest.approx(
        m.peak_acceleration
    )
    from scipy.stats import chi2

    assert pytest.approx(chi2.ppf(0.999, 3), abs=0.01) == NIS_GATE
