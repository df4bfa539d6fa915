"""Averaging camera frames into a world spot (against an independent computation)."""

from __future__ import annotations

import numpy as np
import pytest

from planner.model.transforms import axis_angle_to_matrix, make_T
from planner.servo import SpotFrame, average_frames
from planner.servo.loop import within_tolerance
from planner.servo.measure import SpotMeasurement, merge
from planner.servo.step import ServoSettings

T = make_T(axis_angle_to_matrix([0.3, -0.2, 1.1]), [0.5, -1.0, 0.7])


def test_confidence_weighted_mean_in_the_world() -> None:
    pts = [np.array([0.01, 0.02, 0.8]), np.array([0.012, 0.018, 0.81]), np.array([0.0, 0.0, 0.9])]
    conf = [1.0, 0.5, 0.25]
    m = average_frames([SpotFrame(p, c) for p, c in zip(pts, conf, strict=True)], T)
    assert m is not None
    world = [T[:3, :3] @ p + T[:3, 3] for p in pts]
    expected = sum(c * w for c, w in zip(conf, world, strict=True)) / sum(conf)
    np.testing.assert_allclose(m.spot_world, expected, atol=1e-15)
    spread = np.sqrt(
        sum(c * np.sum((w - expected) ** 2) for c, w in zip(conf, world, strict=True)) / sum(conf)
    )
    assert (m.frames, m.seen) == (3, 3) and m.spread == pytest.approx(spread)
    assert m.confidence == pytest.approx(np.mean(conf))


@pytest.mark.parametrize(
    "bad",
    [SpotFrame(None), SpotFrame(np.array([np.nan, 0, 1])), SpotFrame(np.array([0, 0, np.inf])),
     SpotFrame(np.array([0.0, 0.0, 1.0]), 0.0), SpotFrame(np.array([0.0, 0.0, 1.0]), -0.5),
     SpotFrame(np.array([0.0, 0.0, 1.0]), float("nan")), SpotFrame(np.array([0.0, 1.0])),
     SpotFrame(np.array([0.0, 0.0, 1.0]), 1.5)],
)  # fmt: skip
def test_unseen_and_malformed_frames_count_but_are_not_averaged(bad: SpotFrame) -> None:
    good = SpotFrame(np.array([0.0, 0.0, 1.0]), 0.9)
    m = average_frames([bad, good], T)
    assert m is not None and (m.frames, m.seen) == (2, 1)
    np.testing.assert_allclose(m.spot_world, T[:3, 2] + T[:3, 3], atol=1e-15)
    assert average_frames([bad], T) is None
    assert average_frames([], T) is None


def test_two_measurements_merge_into_the_average_of_all_their_frames() -> None:
    rng = np.random.default_rng(3)
    frames = [SpotFrame(np.array([0.01, 0.02, 0.8]) + rng.normal(0, 2e-4, 3),
                        float(rng.uniform(0.3, 1.0))) for _ in range(7)]  # fmt: skip
    frames.insert(2, SpotFrame(None))  # an unseen frame counts, is not averaged
    a, b, both = (
        average_frames(frames[:3], T),
        average_frames(frames[3:], T),
        average_frames(frames, T),
    )
    assert a is not None and b is not None and both is not None
    m = merge(a, b)
    np.testing.assert_allclose(m.spot_world, both.spot_world, atol=1e-15)
    assert (m.frames, m.seen) == (both.frames, both.seen) == (8, 7)
    assert m.spread == pytest.approx(both.spread, rel=1e-12)
    assert m.confidence == pytest.approx(both.confidence, rel=1e-12)


def test_within_tolerance_needs_the_standard_errors_to_fit() -> None:
    s = ServoSettings(tolerance=0.3e-3, confidence=2.0)
    # 0.25 mm measured, 0.2 mm per-frame spread over 4 frames: 0.1 mm standard error
    m = SpotMeasurement(np.zeros(3), 4, 4, 1.0, 0.2e-3)
    assert not within_tolerance(0.25e-3, m, s) and within_tolerance(0.099e-3, m, s)
    assert within_tolerance(0.25e-3, m, ServoSettings(tolerance=0.3e-3, confidence=0.0))
    with pytest.raises(ValueError, match="confidence"):
        ServoSettings(confidence=float("nan"))
