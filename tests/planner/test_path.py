"""Path NLP: resampling, plane tangents, the curve_path sweep, gap splitting."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.beam import BeamModel
from planner.path import PathOptions, plan_path, resample_polyline, tangents
from planner.path_nlp import constraint_lower_bounds
from planner.system import Targets

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "curve_path.yaml"


@pytest.fixture(scope="module")
def curve():
    from planner.scenario import load_scenario, system_from_scenario, targets_from_scenario

    loaded = load_scenario(SCENARIO)
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    return system, targets, plan_path(system, targets)


def test_resample_spacing_and_ends():
    pts = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.1, 0.05, 0]])
    out, _ = resample_polyline(pts, 0.001)
    steps = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert len(out) == 151
    np.testing.assert_allclose(steps[:99], 0.001, atol=1e-12)  # straight stretch
    np.testing.assert_allclose(out[[0, -1]], pts[[0, -1]], atol=1e-15)
    closed, _ = resample_polyline(pts, 0.001, closed=True)
    assert np.linalg.norm(closed[-1] - pts[0]) > 1e-4  # start not repeated


def test_tangents_orthonormal():
    rng = np.random.default_rng(1)
    for n in rng.normal(size=(20, 3)):
        n /= np.linalg.norm(n)
        E = tangents(n)
        np.testing.assert_allclose(E.T @ E, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(E.T @ n, 0, atol=1e-12)


def test_curve_path_on_target_and_smooth(curve):
    system, targets, res = curve
    assert res.complete and res.ok.all()
    model = BeamModel(system)
    for k in (0, len(targets) // 2, len(targets) - 1):  # independent trace of the solution
        tr = model.trace(res.q[k], targets.points[k], targets.normals[k])
        assert tr.error < 1e-8 and tr.valid
    assert np.nanmax(res.error) < 1e-8
    step = np.abs(np.diff(res.q, axis=0)).max()
    assert step < 0.02  # 1 mm of spot never needs more than ~1 deg of any joint


def test_gap_is_reported(curve):
    system, targets, _ = curve
    far = np.vstack(
        [targets.points[:40], targets.points[39] + [[0, 0, 5.0]], targets.points[40:80]]
    )
    nrm = np.vstack([targets.normals[:40], [[0, 0, 1.0]], targets.normals[40:80]])
    res = plan_path(system, Targets(far, nrm, kind="path"))
    assert [(g.k0, g.k1) for g in res.gaps] == [(40, 41)]
    assert res.gaps[0].reason in {"unreachable", "outside_roi", "joint_limits", "back_face"}
    assert res.ok.sum() == 80 and np.nanmax(res.error) < 1e-8


def test_constraint_lower_bounds():
    has = np.array([1.0, 0.0, 1.0])
    lb = constraint_lower_bounds(2, 3, has, PathOptions(max_incidence_deg=60.0, min_front=0.05))
    assert lb.shape == (3, 4 * 2 + 2)
    np.testing.assert_allclose(lb[0, :4], 1e-6)  # ROI margins of both mirrors (m)
    np.testing.assert_allclose(lb[0, 4:6], 0.05)  # front face: -n.v
    np.testing.assert_allclose(lb[:, -1], [0.5, -np.inf, 0.5])  # cos 60 deg where a normal is
