"""Iterative learning control along a path in the in-process miscalibrated world."""

from __future__ import annotations

import numpy as np
import pytest

from planner.bench.servo_world import UP, SimWorld
from planner.ik import BeamIK
from planner.model.polyline import arc_length
from planner.servo import Corrector, IlcSettings, ilc_update, lowpass_along_arc, polyline_deviation


@pytest.fixture(scope="module")
def world() -> SimWorld:
    return SimWorld(seed=5)


def _path(world: SimWorld) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 40 mm arc-like stroke on the board, 1 mm samples, solved in the model."""
    s = np.linspace(0.0, 1.0, 41)
    P = np.column_stack(
        [-0.52 + 0.04 * s, -0.53 + 0.01 * np.sin(np.pi * s), np.full_like(s, -0.06)]
    )
    ik = BeamIK(world.model)
    Q, q_prev = [], world.model.home
    for p in P:
        sol = ik.solve(p, UP, q_prev)
        assert sol.ok and sol.q is not None
        Q.append(sol.q)
        q_prev = sol.q
    return P, np.array(Q), arc_length(P)


def test_ilc_brings_a_path_from_millimetres_to_half_a_millimetre_on_the_second_pass(
    world: SimWorld,
) -> None:
    P, Q, arc = _path(world)
    true1 = np.array([world.true_spot(q) for q in Q])
    before = np.linalg.norm(true1 - P, axis=1)
    assert before.min() > 3e-3  # open loop: several millimetres everywhere
    # first pass: one camera frame at every second sample (a 30 Hz camera on a moving spot)
    idx = np.arange(0, len(P), 2)
    seen = [(k, world.measure(Q[k], 1)) for k in idx]
    marc = np.array([arc[k] for k, m in seen if m is not None])
    merr = np.array([m.spot_world - P[k] for k, m in seen if m is not None])
    assert len(marc) == len(idx)
    up = ilc_update(Corrector(world.model), Q, P, np.tile(UP, (len(P), 1)), arc, marc, merr)
    assert up.failures == [] and up.q.shape == Q.shape
    np.testing.assert_allclose(up.q, Q + up.dq)
    true2 = np.array([world.true_spot(q) for q in up.q])
    after = np.linalg.norm(true2 - P, axis=1)
    print(f"ILC per-sample error: before max {1e3 * before.max():.2f} mm, after max "
          f"{1e3 * after.max():.3f} mm")  # fmt: skip
    assert after.max() <= 0.5e-3
    assert polyline_deviation(true2, P).max() <= 0.5e-3 < polyline_deviation(true1, P).max()


def test_ilc_refuses_mismatched_or_empty_measurements(world: SimWorld) -> None:
    P, Q, arc = _path(world)
    c = Corrector(world.model)
    with pytest.raises(ValueError, match="finite measured"):
        ilc_update(c, Q, P, None, arc, np.array([0.01]), np.full((1, 3), np.nan))
    with pytest.raises(ValueError, match="M x 3"):
        ilc_update(c, Q, P, None, arc, np.array([0.01, 0.02]), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="K x 3"):
        ilc_update(c, Q, P[:-1], None, arc, np.array([0.01]), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="non-decreasing"):
        ilc_update(c, Q, P, None, arc[::-1], np.array([0.01]), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="smoothing"):
        IlcSettings(smoothing=0.0)


def test_lowpass_keeps_a_trend_and_suppresses_noise() -> None:
    rng = np.random.default_rng(0)
    arc = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 400))
    trend = np.column_stack([np.sin(arc / 0.05), 2.0 + 0 * arc])
    noise = rng.normal(0, 1.0, trend.shape)
    out = lowpass_along_arc(arc, trend + noise, 0.004)
    inner = slice(40, -40)
    # a Gaussian of 4 mm over ~1 mm samples averages ~14 samples: noise std / ~3.8
    assert np.std((out - trend)[inner]) < 0.4
    np.testing.assert_allclose(lowpass_along_arc(arc, trend[:, 1:], 0.004), 2.0, atol=1e-12)


def test_polyline_deviation_against_known_distances() -> None:
    poly = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 1.0, 0]])
    pts = np.array([[0.5, 0.2, 0], [1.3, 0.5, 0], [-0.3, 0.4, 0], [1.0, 2.0, 0.0]])
    np.testing.assert_allclose(polyline_deviation(pts, poly), [0.2, 0.3, 0.5, 1.0])
