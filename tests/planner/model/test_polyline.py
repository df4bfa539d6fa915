"""One polyline module: runs of good samples, and the one resampler behind both entry points."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.model.polyline import arc_length, resample_path, resample_polyline, runs


@settings(max_examples=200, deadline=None)
@given(mask=st.lists(st.booleans(), max_size=40), offset=st.integers(0, 100))
def test_runs_by_brute_force(mask: list[bool], offset: int) -> None:
    expected, start = [], None
    for k, good in enumerate([*mask, False]):
        if good and start is None:
            start = k
        elif not good and start is not None:
            expected.append((start + offset, k + offset))
            start = None
    assert runs(np.array(mask, dtype=bool), offset) == expected


def test_equal_spacing_resampler_is_the_path_resampler() -> None:
    """resample_polyline = resample_path at the length-dividing spacing (a corner falls
    between samples here, so an arc-length interpolation would differ)."""
    pts = np.array([[0.0, 0, 0], [0.1037, 0, 0], [0.1037, 0.0512, 0], [0.02, 0.07, 0.01]])
    nrm = np.tile([0.0, 0.0, 1.0], (4, 1))
    for closed in (False, True):
        out, n_out = resample_polyline(pts, 0.001, closed, nrm)
        length = arc_length(np.vstack([pts, pts[:1]]) if closed else pts)[-1]
        step = length / np.ceil(length / 0.001)
        ref, n_ref = resample_path(pts, spacing=step, normals=nrm, closed=closed)
        ref, n_ref = (ref[:-1], n_ref[:-1]) if closed else (ref, n_ref)  # type: ignore[index]
        np.testing.assert_array_equal(out, ref)
        np.testing.assert_array_equal(n_out, n_ref)  # type: ignore[arg-type]
        chords = np.linalg.norm(np.diff(out, axis=0), axis=1)
        np.testing.assert_allclose(chords[:-1], step, atol=1e-12)
