"""Scene-object motion: offsets against closed forms, velocity against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from planner.model.motion import ObjectMotion


def test_sine_offset_is_the_closed_form() -> None:
    m = ObjectMotion.sine([0, 0, 2], 0.005, 0.25)  # axis normalised
    t = np.array([0.0, 1.0, 2.0, 3.0, 0.5, 1e9 + 1.0])
    expected = 0.005 * np.sin(2 * np.pi * 0.25 * t)
    np.testing.assert_allclose(m.offset(t)[:, 2], expected, atol=1e-9)
    np.testing.assert_allclose(m.offset(t)[:, :2], 0.0)
    assert m.offset(1.0).shape == (3,)
    assert m.period == 4.0
    assert m.peak_speed == pytest.approx(2 * np.pi * 0.25 * 0.005)


def test_linear_motion_goes_and_comes_back() -> None:
    v = np.array([0.02, -0.01, 0.0])
    m = ObjectMotion.linear(v, 2.0)
    np.testing.assert_allclose(m.offset(0.0), 0.0)
    np.testing.assert_allclose(m.offset(1.0), v * 1.0)
    np.testing.assert_allclose(m.offset(2.0), v * 2.0)
    np.testing.assert_allclose(m.offset(3.0), v * 1.0)
    np.testing.assert_allclose(m.offset(4.0), 0.0, atol=1e-15)
    np.testing.assert_allclose(m.offset(5.5), v * 1.5)  # second period
    np.testing.assert_allclose(m.velocity([0.5, 2.5]), [v, -v])


@pytest.mark.parametrize(
    "motion",
    [ObjectMotion.sine([1, 1, 0], 0.01, 0.7), ObjectMotion.linear([0.0, 0.03, 0.01], 0.8)],
)
def test_velocity_is_the_derivative_of_the_offset(motion: ObjectMotion) -> None:
    t = np.linspace(0.013, 5.0, 97)
    t = t[np.abs(np.mod(t, motion.period) - motion.duration) > 1e-3]  # not on a turnaround
    h = 1e-6
    fd = (motion.offset(t + h) - motion.offset(t - h)) / (2 * h)
    np.testing.assert_allclose(motion.velocity(t), fd, atol=1e-6)


def test_pose_translates_only() -> None:
    T = np.eye(4)
    T[:3, :3] = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    T[:3, 3] = [1, 2, 3]
    m = ObjectMotion.sine([0, 0, 1], 0.005, 0.25)
    P = m.pose(T, 1.0)
    np.testing.assert_allclose(P[:3, :3], T[:3, :3])
    np.testing.assert_allclose(P[:3, 3], [1, 2, 3.005])
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])  # input untouched
