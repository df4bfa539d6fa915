"""Closed-form cases of the numpy distances, and a brute-force cross-check."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.model.transforms import make_T, rpy_to_matrix
from planner.verify.distances import (
    box_box,
    capsule_capsule,
    point_box,
    point_segment,
    point_sphere,
    segment_box,
    segment_segment,
    segment_sphere,
)

A = np.array


def test_parallel_segments_distance_is_their_offset():
    d, x, y = segment_segment(A([0, 0, 0.0]), A([1, 0, 0.0]), A([0.5, 0.3, 0.0]), A([2, 0.3, 0.0]))
    assert d == pytest.approx(0.3, abs=1e-15)
    assert np.linalg.norm(x - y) == pytest.approx(0.3, abs=1e-15)
    assert 0.5 <= x[0] <= 1.0  # on the overlap


def test_parallel_segments_without_overlap_meet_end_to_end():
    d, x, y = segment_segment(A([0, 0, 0.0]), A([1, 0, 0.0]), A([1.4, 0.3, 0.0]), A([2, 0.3, 0.0]))
    assert d == pytest.approx(0.5, abs=1e-15)
    np.testing.assert_allclose(x, [1, 0, 0])
    np.testing.assert_allclose(y, [1.4, 0.3, 0])


def test_crossing_segments_distance_is_the_height_between_them():
    d, x, y = segment_segment(A([-1, 0, 0.0]), A([1, 0, 0.0]), A([0, -1, 0.2]), A([0, 1, 0.2]))
    assert d == pytest.approx(0.2, abs=1e-15)
    np.testing.assert_allclose(x, [0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(y, [0, 0, 0.2], atol=1e-15)


def test_degenerate_segment_is_a_point():
    d, x, y = segment_segment(A([0, 1, 0.0]), A([0, 1, 0.0]), A([-1, 0, 0.0]), A([1, 0, 0.0]))
    assert d == pytest.approx(1.0)
    np.testing.assert_allclose(x, [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(y, [0, 0, 0], atol=1e-15)


def test_capsules_touching_and_overlapping():
    p0, p1 = A([0, 0, 0.0]), A([1, 0, 0.0])
    q0, q1 = A([0.5, 0.1, -1.0]), A([0.5, 0.1, 1.0])
    d, pa, pb = capsule_capsule(p0, p1, 0.05, q0, q1, 0.05)
    assert d == pytest.approx(0.0, abs=1e-15)
    d, pa, pb = capsule_capsule(p0, p1, 0.08, q0, q1, 0.05)
    assert d == pytest.approx(-0.03, abs=1e-15)
    np.testing.assert_allclose(pa, [0.5, 0.08, 0], atol=1e-15)
    np.testing.assert_allclose(pb, [0.5, 0.05, 0], atol=1e-15)


def test_point_in_box_is_negative_depth_to_nearest_face():
    T = make_T(rpy_to_matrix([0.3, -0.2, 1.0]), [0.1, 0.2, 0.3])
    x = T @ A([0.05, 0.02, -0.01, 1.0])
    d, face = point_box(x[:3], T, A([0.2, 0.1, 0.4]))
    assert d == pytest.approx(-0.03, abs=1e-14)  # gaps to the faces: 0.05, 0.03, 0.19 m
    assert np.linalg.norm(face - x[:3]) == pytest.approx(0.03, abs=1e-14)


def test_point_outside_box_corner():
    d, c = point_box(A([0.4, 0.3, 0.2]), np.eye(4), A([0.2, 0.2, 0.2]))
    assert d == pytest.approx(np.linalg.norm([0.3, 0.2, 0.1]))
    np.testing.assert_allclose(c, [0.1, 0.1, 0.1])


def test_segment_through_box_is_zero_and_beside_it_is_the_gap():
    T = make_T(rpy_to_matrix([0, 0, np.pi / 4]), [1, 1, 0])
    assert segment_box(A([0, 0, 0.0]), A([2, 2, 0.0]), T, A([0.1, 0.1, 0.1]))[0] == 0.0
    d, x = segment_box(
        A([0, 1, 0.3]), A([2, 1, 0.3]), np.eye(4) @ make_T(p=[1, 1, 0]), A([0.2, 0.2, 0.2])
    )
    assert d == pytest.approx(0.2, abs=1e-12)
    assert 0.9 - 1e-6 <= x[0] <= 1.1 + 1e-6 and x[2] == pytest.approx(0.3)


def test_sphere_distances():
    assert point_sphere(A([0, 0, 2.0]), A([0, 0, 0.0]), 0.5)[0] == pytest.approx(1.5)
    assert point_sphere(A([0, 0, 0.1]), A([0, 0, 0.0]), 0.5)[0] == pytest.approx(-0.4)
    d, x = segment_sphere(A([-1, 0.3, 0.0]), A([1, 0.3, 0.0]), A([0, 0, 0.0]), 0.1)
    assert d == pytest.approx(0.2)
    np.testing.assert_allclose(x, [0, 0.3, 0], atol=1e-15)


def test_box_box_gap_and_overlap():
    e = A([0.2, 0.2, 0.2])
    assert box_box(np.eye(4), e, make_T(p=[0.5, 0, 0]), e) == pytest.approx(0.3, abs=1e-12)
    R = rpy_to_matrix([0, 0, np.pi / 4])  # a corner pointing at the other box
    gap = 0.5 - 0.1 - 0.1 * np.sqrt(2)
    assert box_box(np.eye(4), e, make_T(R, [0.5, 0, 0]), e) == pytest.approx(gap, abs=1e-12)
    # a plate crossing through the middle of a cube: they meet
    assert box_box(np.eye(4), e, np.eye(4), A([1.0, 0.01, 0.01])) == 0.0


vec = st.lists(st.floats(-1, 1, allow_nan=False), min_size=3, max_size=3).map(np.array)


@settings(max_examples=60, deadline=None)
@given(vec, vec, vec, vec)
def test_segment_segment_matches_dense_sampling(p0, p1, q0, q1):
    d, x, y = segment_segment(p0, p1, q0, q1)
    s = np.linspace(0, 1, 401)
    P = p0 + s[:, None] * (p1 - p0)
    Q = q0 + s[:, None] * (q1 - q0)
    brute = np.linalg.norm(P[:, None] - Q[None], axis=2).min()
    step = (np.linalg.norm(p1 - p0) + np.linalg.norm(q1 - q0)) / 400
    assert d <= brute + 1e-12
    assert d >= brute - step - 1e-12  # step may be 0 (degenerate segments): allow round-off
    assert np.linalg.norm(x - y) == pytest.approx(d, abs=1e-12)
    assert point_segment(x, p0, p1)[0] < 1e-12 and point_segment(y, q0, q1)[0] < 1e-12
