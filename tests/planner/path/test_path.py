"""Path NLP: resampling, plane tangents, the curve_path sweep, gap splitting."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.ik.closed_form import ClosedForm
from planner.model.system import Targets
from planner.path.nlp import constraint_lower_bounds
from planner.path.solve import PathOptions, plan_path, resample_polyline, tangents
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "curve_path.yaml"


@pytest.fixture(scope="module")
def curve():
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario

    loaded = load_scenario(SCENARIO)
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    return system, targets, plan_path(system, targets, seeder=ClosedForm(system))


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
    res = plan_path(system, Targets(far, nrm, kind="path"), seeder=ClosedForm(system))
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


def test_curve_path_is_exact_after_polish(curve):
    """The final Gauss-Newton polish brings every sample to machine precision (IPOPT alone
    stops at ~1e-11 m), checked by the independent numpy beam model."""
    system, targets, res = curve
    model = BeamModel(system)
    errs = [model.trace(q, p, n).error for q, p, n in zip(res.q, targets.points, targets.normals,
                                                          strict=True)]  # fmt: skip
    assert max(errs) < 1e-14


def test_tangents_batch_matches_tangents():
    from planner.path.nlp import tangents_batch

    rng = np.random.default_rng(3)
    N = rng.normal(size=(9, 3))
    N[4] = [0.95, 0.1, 0.0]  # the other reference axis
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    ref = np.concatenate([tangents(n) for n in N], axis=1)
    np.testing.assert_allclose(tangents_batch(N), ref, atol=1e-15)


def test_coarse_indices_spacing_and_ends():
    from planner.path.warm import coarse_indices

    idx = coarse_indices(1000, 0.15e-3, 1e-3)
    assert idx[0] == 0 and idx[-1] == 999
    assert set(np.diff(idx[:-1])) == {7}  # 1 mm / 0.15 mm rounds to 7
    np.testing.assert_array_equal(coarse_indices(5, 2e-3, 1e-3), np.arange(5))


@pytest.fixture(scope="module")
def fine(curve):
    """The curve resampled every 0.25 mm, with its context and the per-sample chain."""
    from planner.path.warm import PathContext, continuation_chain

    system, targets, _ = curve
    pts, nrm = resample_polyline(targets.points, 0.25e-3, False, targets.normals)
    pts, nrm = pts[:240], nrm[:240]
    ctx = PathContext(system, Targets(pts, nrm, kind="path"), PathOptions(), ClosedForm(system))
    Q, NB, why = continuation_chain(ctx, system.home)
    assert all(w is None for w in why)
    return ctx, Q, NB


def test_project_reaches_targets_and_never_worsens(fine):
    from planner.path.warm import project

    ctx, Q, NB = fine
    ks = np.arange(len(Q))
    rng = np.random.default_rng(0)
    Q0 = Q + rng.normal(scale=2e-3, size=Q.shape)  # ~mm spot errors
    Q0[5] = np.nan  # a bad row stays bad, the others are unaffected
    Qp, _, err = project(ctx, ks, Q0, NB)
    model = BeamModel(ctx.system)
    good = np.delete(ks, 5)
    before = [model.trace(Q0[k], ctx.P[k], ctx.nbar[k]).error for k in good]
    after = [model.trace(Qp[k], ctx.P[k], ctx.nbar[k]).error for k in good]
    assert min(before) > 1e-6 and max(after) < 1e-14
    np.testing.assert_allclose(err[good], after, atol=1e-14)
    assert np.all(np.isnan(Qp[5]))
    # the step is the minimum-norm one: far smaller than the perturbation it undoes
    assert np.abs(Qp[good] - Q0[good]).max() < 2e-2


def test_valid_samples_agrees_with_why(fine):
    from planner.path.nlp import sample_function
    from planner.path.warm import valid_samples

    ctx, Q, NB = fine
    ks = np.arange(len(Q))
    Qb = Q.copy()
    Qb[10, 2] = ctx.upper[2] + 0.1  # beyond the elbow limit
    Qb[20] += 0.3  # spot far off
    ok = valid_samples(ctx, ks, Qb, NB)

    def sample(k: int) -> tuple[np.ndarray, np.ndarray]:
        out = sample_function(ctx.kin)(q=Qb[k], **ctx.geo, target=ctx.P[k], nbar=NB[k],
                                       has_normal=1.0, tangents=tangents(NB[k]))  # fmt: skip
        return out["g"], out["h"]

    G, H = sample(30)
    assert ctx.why(30, Qb[30], np.asarray(G), np.asarray(H)) is None
    for k in (10, 20, 30, 100):
        G, H = sample(k)
        assert ok[k] == (ctx.why(k, Qb[k], np.asarray(G), np.asarray(H)) is None)
    assert not ok[10] and not ok[20] and ok.sum() == len(Q) - 2


def test_coarse_to_fine_warm_start_matches_the_chain(fine):
    """The spline-and-project warm start lands on every target and stays within a few mrad
    of the per-sample continuation chain it replaces."""
    from planner.path.solve import _coarse_to_fine, arc_length

    ctx, Q, _ = fine
    warm = _coarse_to_fine(ctx, ctx.system.home, arc_length(ctx.P), False)
    assert warm is not None
    Qw, _ = warm
    model = BeamModel(ctx.system)
    assert max(model.trace(Qw[k], ctx.P[k], ctx.nbar[k]).error for k in range(len(Qw))) < 1e-12
    assert np.abs(Qw - Q).max() < 5e-3


def test_acceleration_weight_scaling():
    from planner.path.solve import acceleration_weight

    o = PathOptions(weight_acceleration=2e-6, acceleration_spacing=1e-3)
    assert acceleration_weight(o, 2e-3) == 2e-6  # coarser than the reference: unchanged
    assert acceleration_weight(o, 0.5e-3) == pytest.approx(0.5e-6)  # (0.5)^2


def test_fine_closed_path_coarse_to_fine(curve):
    """A closed 10 mm circle every 0.25 mm: warm-started coarse-to-fine (periodic spline),
    one closed NLP, every sample exact, and the joints close up smoothly."""
    import planner.path.solve as path_mod

    system, _, _ = curve
    th = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    ring = np.column_stack([-0.4918 + 0.01 * np.cos(th), -0.5679 + 0.01 * np.sin(th),
                            np.full(40, -0.06)])  # fmt: skip
    pts, nrm = resample_polyline(ring, 0.25e-3, True, np.tile([0.0, 0.0, 1.0], (40, 1)))
    calls = []
    real = path_mod._coarse_to_fine
    path_mod._coarse_to_fine = lambda *a: calls.append(a[-1]) or real(*a)  # type: ignore[assignment]
    try:
        res = plan_path(system, Targets(pts, nrm, kind="path", closed=True),
                        seeder=ClosedForm(system))  # fmt: skip
    finally:
        path_mod._coarse_to_fine = real
    assert calls == [True] and res.complete
    assert res.segments[-1].status == "Solve_Succeeded"
    assert np.nanmax(res.error) < 1e-14
    steps = np.abs(np.diff(np.vstack([res.q, res.q[:1]]), axis=0)).max(axis=1)
    assert steps[-1] < 3 * np.median(steps) + 1e-4  # the wrap-around step is like the others


def test_compiled_functions_match_the_sx_originals(tmp_path, monkeypatch):
    """The C-compiled per-sample Hessian gives the SX virtual machine's numbers; a library
    already in the cache is loaded without compiling again; without a compiler the original
    function is used."""
    import casadi as ca

    from planner.model.kinematics import RobotKinematics
    from planner.path.nlp import _compiled, compiled, sample_hessian

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    f = sample_hessian((RobotKinematics.ur5e(),))
    fc = compiled(f)
    assert fc is not f and list(tmp_path.joinpath("beamrelay").glob("*.so"))
    rng = np.random.default_rng(2)
    args = [rng.normal(size=f.size_in(i)) for i in range(f.n_in())]
    np.testing.assert_allclose(np.asarray(fc(*args)), np.asarray(f(*args)), rtol=1e-12, atol=1e-12)
    assert isinstance(fc, ca.Function)
    # a later run finds the library on disk and loads it without the compiler
    _compiled.cache_clear()
    monkeypatch.setattr("subprocess.run", lambda *a, **k: pytest.fail("recompiled"))
    assert compiled(f) is not f
    monkeypatch.setattr("shutil.which", lambda name: None)
    assert compiled(f) is f


def along_own_beams(system, res, targets, d: float) -> np.ndarray:
    """Plain numpy: every sample moved ``d`` m along the last ray of its solved beam (as a
    landing moves a camera-frame path onto its surface)."""
    model = BeamModel(system)
    rays = [model.trace(q, p, n).dirs[-1] for q, p, n in
            zip(res.q, targets.points, targets.normals, strict=True)]  # fmt: skip
    return targets.points + d * np.asarray(rays)


def test_a_path_moved_along_its_beams_reuses_the_solved_joints(curve):
    """Samples moved along their own solved beams are hit by the same joints: given them as
    ``q_warm``, the sweep takes them (no NLP run) and every sample lands on its moved point
    (independent numpy trace), as smooth as before."""
    system, targets, res = curve
    moved = Targets(along_own_beams(system, res, targets, 0.004), targets.normals, kind="path")
    again = plan_path(system, moved, q_warm=res.q, seeder=ClosedForm(system))
    assert again.complete and [s.status for s in again.segments] == ["previous path"]
    model = BeamModel(system)
    errs = [model.trace(q, p, n).error for q, p, n in
            zip(again.q, moved.points, moved.normals, strict=True)]  # fmt: skip
    assert max(errs) < 1e-12
    assert np.abs(again.q - res.q).max() < 1e-6  # the beams already passed through them
    assert np.abs(np.diff(again.q, axis=0)).max() < 0.02


def test_a_warm_start_that_does_not_fit_is_not_used(curve):
    """``q_warm`` with a missing row, or of another path length, leaves the sweep to its own
    warm start and NLP: the same result as without it."""
    system, targets, res = curve
    holed = res.q.copy()
    holed[5] = np.nan
    for q_warm in (holed, res.q[:-1]):
        again = plan_path(system, targets, q_warm=q_warm, seeder=ClosedForm(system))
        assert "previous path" not in [s.status for s in again.segments]
        np.testing.assert_allclose(again.q, res.q, atol=1e-9)
