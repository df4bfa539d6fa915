"""One plane basis for the IK NLP's spot plane and the path NLP's target tangents."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.model.transforms import plane_bases, plane_basis
from planner.path.nlp import tangents, tangents_batch

vec = st.tuples(*[st.floats(-1, 1)] * 3).map(np.array).filter(lambda x: np.linalg.norm(x) > 0.1)


@settings(max_examples=200, deadline=None)
@given(n=vec)
def test_plane_basis_is_a_right_handed_frame_on_the_normal(n: np.ndarray) -> None:
    B = plane_basis(n)
    np.testing.assert_allclose(B.T @ B, np.eye(3), atol=1e-14)
    assert np.linalg.det(B) > 0
    np.testing.assert_allclose(B[:, 0], n / np.linalg.norm(n), atol=1e-15)
    u = n / np.linalg.norm(n)
    np.testing.assert_allclose(tangents(u), B[:, 1:], atol=1e-15)


def test_batch_equals_single() -> None:
    N = np.random.default_rng(0).normal(size=(25, 3))
    N[3] = [1.0, 0.0, 0.0]  # near the x axis: the other helper vector
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    batch = plane_bases(N)
    E = tangents_batch(N)
    for k, n in enumerate(N):
        np.testing.assert_array_equal(batch[k], plane_basis(n))
        np.testing.assert_array_equal(E[:, 2 * k : 2 * k + 2], tangents(n))
