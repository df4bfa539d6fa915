"""The console's cloud: decode the camera's wire format, map to the world, decimate."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.console.cloud import cloud_from_sample, decimate, depth_colors
from planner.errors import InputError
from planner.model.transforms import make_T
from schemas.points import points_metadata


def sample(pts: np.ndarray, **extra: object) -> tuple[bytes, bytes]:
    pts = np.ascontiguousarray(pts, dtype=np.float32)
    return pts.tobytes(), json.dumps(points_metadata(pts, 12.5, 7, dict(extra))).encode()


def test_points_are_mapped_to_the_world_with_the_camera_pose() -> None:
    rng = np.random.default_rng(0)
    p_cam = rng.uniform([-0.3, -0.2, 0.5], [0.3, 0.2, 1.2], (500, 3))
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # optical frame looking along +x
    T = make_T(R, [-1.0, -1.0, 0.5])
    cloud = cloud_from_sample(*sample(p_cam), T, max_points=10_000)
    expected = p_cam.astype(np.float32).astype(float) @ R.T + T[:3, 3]
    assert np.allclose(cloud.points, expected, atol=1e-6)
    assert cloud.colors.shape == (500, 3) and cloud.colors.dtype == np.uint8
    assert (cloud.t, cloud.seq) == (12.5, 7)


def test_rgb_fields_give_the_colours_and_non_finite_rows_are_dropped() -> None:
    pts = np.array([[0, 0, 1, 1.0, 0.0, 0.5], [np.nan, 0, 1, 0, 0, 0], [0, 0, 2, 0, 1, 0]])
    cloud = cloud_from_sample(*sample(pts), np.eye(4))
    assert len(cloud.points) == 2
    assert cloud.colors.tolist() == [[255, 0, 127], [0, 255, 0]]


def test_decimation_keeps_an_even_stride_within_the_budget() -> None:
    P = np.zeros((407_040, 3))
    for budget in (1, 1000, 50_000, 407_040, 10**6):
        idx = decimate(P, budget)
        assert len(idx) <= budget
        assert len(idx) >= min(budget, len(P)) // 2  # never throws away more than half
        assert np.all(np.diff(idx) == idx[1] - idx[0]) if len(idx) > 1 else True
    assert len(decimate(P, 10**6)) == len(P)
    with pytest.raises(ValueError):
        decimate(P, 0)


def test_depth_ramp_spans_near_to_far_at_constant_saturation() -> None:
    import colorsys

    z = np.linspace(0.5, 1.5, 101)
    c = depth_colors(z).astype(int)
    for k in (0, 13, 50, 77, 100):  # against the standard library's HSV conversion
        hue = (
            50.0
            + 180.0
            * np.clip((z[k] - np.percentile(z, 2)) / np.ptp(np.percentile(z, [2, 98])), 0, 1)
        ) / 360
        expected = np.round(255 * np.array(colorsys.hsv_to_rgb(hue, 0.8, 0.95)))
        assert np.abs(c[k] - expected).max() <= 1, (k, c[k], expected)
    assert np.all(c.max(axis=1) - c.min(axis=1) >= 190)  # never a grey
    assert depth_colors(np.zeros(0)).shape == (0, 3)
    assert np.all(depth_colors(np.full(5, 0.7)) == depth_colors(np.full(5, 0.7))[0])


@pytest.mark.parametrize(
    ("payload", "attachment", "match"),
    [
        (b"", b"not json", "bad points metadata"),
        (b"", b'{"fields": ["x"]}', "bad points metadata"),
        (b"\0" * 12, b'{"schema": "other", "dtype": "float32", "fields": ["x","y","z"], "count": 1}',
         "expected beamrelay.points/1"),
        (b"\0" * 12, b'{"schema": "beamrelay.points/1", "dtype": "float64", "fields": ["x","y","z"],'
         b' "count": 1}', "float32"),
        (b"\0" * 8, b'{"schema": "beamrelay.points/1", "dtype": "float32", "fields": ["x","y"],'
         b' "count": 1}', "fields"),
        (b"\0" * 11, b'{"schema": "beamrelay.points/1", "dtype": "float32", "fields": ["x","y","z"],'
         b' "count": 1}', "11 bytes for 1 x 3"),
        (b"", b'{"schema": "beamrelay.points/1", "dtype": "float32", "fields": ["x","y","z"],'
         b' "count": 1e12}', "count"),
        (b"", b'{"schema": "beamrelay.points/1", "dtype": "float32", "fields": ["x","y","z"],'
         b' "count": -1}', "count"),
    ],
)  # fmt: skip
def test_malformed_samples_are_input_errors(payload: bytes, attachment: bytes, match: str) -> None:
    with pytest.raises(InputError, match=match):
        cloud_from_sample(payload, attachment, np.eye(4))
