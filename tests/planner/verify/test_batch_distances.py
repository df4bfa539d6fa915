"""The checker's batched distances against its scalar ones (planner.verify.distances, each
tested against brute force) and against dense sampling."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.model.transforms import make_T, rpy_to_matrix
from planner.verify import batch_distances as bd
from planner.verify import distances as sd

vec = st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=3, max_size=3).map(np.array)


@settings(max_examples=60, deadline=None)
@given(vec, vec, vec, vec, st.floats(0.0, 1.0))
def test_segment_segment(p0, p1, q0, q1, parallel):  # type: ignore[no-untyped-def]
    if parallel > 0.7:  # exactly parallel and degenerate cases too
        q1 = q0 + (p1 - p0) * (parallel - 0.85) * 4
    got = bd.segment_segment(p0[None], p1[None], q0[None], q1[None])[0]
    assert abs(got - sd.segment_segment(p0, p1, q0, q1)[0]) < 1e-9


@settings(max_examples=60, deadline=None)
@given(vec, vec, vec, vec, vec.map(lambda v: np.abs(v) * 0.5 + 0.01))
def test_segment_box(p0, p1, c, rpy, ext):  # type: ignore[no-untyped-def]
    T = make_T(rpy_to_matrix(rpy), c)
    got = bd.segment_box(p0[None], p1[None], T[None], ext)[0]
    assert abs(got - sd.segment_box(p0, p1, T, ext)[0]) < 1e-7  # golden section: ~1e-8


@settings(max_examples=30, deadline=None)
@given(vec, vec, vec, vec, vec.map(lambda v: np.abs(v) * 0.3 + 0.01),
       vec.map(lambda v: np.abs(v) * 0.3 + 0.01))  # fmt: skip
def test_box_box(c1, r1, c2, r2, e1, e2):  # type: ignore[no-untyped-def]
    T1, T2 = make_T(rpy_to_matrix(r1), c1), make_T(rpy_to_matrix(r2), c2)
    got = bd.box_box(T1[None], e1, T2[None], e2)[0]
    assert abs(got - sd.box_box(T1, e1, T2, e2)) < 1e-7


def test_point_box_inside_is_zero_and_outside_exact() -> None:
    T = make_T(rpy_to_matrix([0.3, -0.2, 1.0]), [0.1, 0.2, 0.3])
    ext = np.array([0.2, 0.4, 0.6])
    X = np.random.default_rng(1).uniform(-1, 1, (200, 3))
    got = bd.point_box(X, np.broadcast_to(T, (200, 4, 4)), ext)
    ref = np.array([max(sd.point_box(x, T, ext)[0], 0.0) for x in X])
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_segment_hull_meets_matches_sampling() -> None:
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(3)
    pts = rng.normal(size=(30, 3)) * [0.2, 0.1, 0.15]
    hull = ConvexHull(pts)
    A, B = rng.uniform(-0.5, 0.5, (400, 3)), rng.uniform(-0.5, 0.5, (400, 3))
    got = bd.segment_hull_meets(A, B, hull.equations)
    s = np.linspace(0, 1, 2001)[:, None, None]
    X = A[None] + s * (B - A)[None]  # (2001, 400, 3)
    inside = ((X @ hull.equations[:, :3].T + hull.equations[:, 3]) <= 0).all(axis=2).any(axis=0)
    # sampling can only miss a grazing cut; it never finds one the clipping misses
    assert np.all(got | ~inside)
    assert (got & ~inside).sum() <= 2 and got.sum() > 50
