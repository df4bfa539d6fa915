"""Trajectories under the safety rules: moves detoured around arm collisions, targets
dropped when no safe move exists, the beam checked at every laser-on sample, path samples
that break a rule becoming gaps; all re-checked with the checker's numpy geometry."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.model.transforms import make_T
from planner.path.timing import ruckig_move
from planner.safety import check_sweep, sphere
from planner.safety.model import Safety, SafetySettings
from planner.safety.trajectory import SafeMover, check_trajectory
from planner.verify.check import check_plan
from tests.paths import REPO
from tests.planner.safety.numpy_rules import hits, setup
from tests.planner.safety.worlds import UPRIGHT, relay

RATE = 500.0


def _swing() -> tuple[np.ndarray, np.ndarray]:
    """arm1 stretched out, panning 180 deg through arm0's space (gap 0.9 m)."""
    q0 = np.r_[UPRIGHT, [np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0]]
    q1 = np.r_[UPRIGHT, [3 * np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0]]
    return q0, q1


def test_colliding_move_is_detoured_through_a_waypoint() -> None:
    system = relay(gap=0.9)
    rules = Safety(system)
    q0, q1 = _swing()
    lim = system.limits
    direct = ruckig_move(q0, q1, lim, RATE)[0]
    assert check_sweep(rules.world, np.arange(len(direct)) / RATE, direct) is not None
    mover = SafeMover(rules, ruckig_move)
    Q, QD, _ = mover(q0, q1, lim, RATE)
    assert mover.detours == 1 and not mover.failures
    np.testing.assert_allclose(Q[0], q0)
    np.testing.assert_allclose(Q[-1], q1)
    assert check_sweep(rules.world, np.arange(len(Q)) / RATE, Q) is None
    # every sample clear by the independent geometry too, within the limits
    s = setup(system)
    assert all(not hits(s, system, q) for q in Q[::5])
    assert np.all(np.abs(QD) <= lim.velocity * (1 + 1e-9))
    # the waypoint is a rest point: velocity zero somewhere inside
    assert np.any(np.all(np.abs(QD[5:-5]) < 1e-12, axis=1))


def test_move_without_a_detour_is_reported() -> None:
    system = relay(gap=0.9)
    rules = Safety(system, settings=SafetySettings(clearance=0.45))  # bases 0.9 - 0.152 apart
    q0, q1 = _swing()
    mover = SafeMover(rules, ruckig_move, tries=5)
    mover(q0, q1, system.limits, RATE)
    assert mover.detours == 0 and len(mover.failures) == 1
    f = mover.failures[0]
    np.testing.assert_allclose(f.q1, q1)
    assert f.violation.reason == "collision" and f.violation.clearance.required == 0.45


def test_beam_is_checked_at_every_laser_on_sample() -> None:
    system = relay()
    q = np.r_[UPRIGHT, UPRIGHT]
    rules = Safety(system)
    from planner.safety.beam import trace

    pts, v = trace(rules.world, q)
    assert np.all(np.isfinite(pts))
    target = pts[-1] + 0.5 * v
    eye = sphere("eye", 0.01, make_T(p=pts[-1] + 0.3 * v))  # on the last segment
    guarded = Safety(system, keep_out=[eye])
    t = np.arange(30) / RATE
    Q = np.tile(q, (30, 1))
    moving = [("move", 0.0, t[9]), ("dwell", t[9], t[19]), ("move", t[19], t[-1])]
    res = check_trajectory(guarded, t, Q, moving, target[None])
    assert res.beam is not None and res.beam_samples == 1  # the dwell: one configuration
    t_hit, violation = res.beam
    assert t[9] <= t_hit <= t[19] and violation.reason == "keep_out"
    assert violation.evidence["b"] == "keep_out/eye"
    # the laser off (moves only): nothing to check
    off = [("move", 0.0, t[-1])]
    assert check_trajectory(guarded, t, Q, off, target[None]).beam is None
    # explicit laser_on intervals replace the segments
    res = check_trajectory(guarded, t, Q, off, target[None], laser_on=[[t[3], t[4]]])
    assert res.beam is not None and t[3] <= res.beam[0] <= t[4]


@pytest.fixture(scope="module")
def curve():  # type: ignore[no-untyped-def]
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario

    scn = load_scenario(REPO / "scenarios" / "curve_path.yaml")
    system = system_from_scenario(scn)
    return scn, system, targets_from_scenario(scn, system)


def test_path_samples_into_keep_out_become_gaps(curve) -> None:  # type: ignore[no-untyped-def]
    from planner.plan.scenario_planner import ik_options, solve_path

    scn, system, targets = curve
    k = len(targets) // 2
    eye = sphere("eye", 0.004, make_T(p=targets.points[k]))
    rules = Safety(system, keep_out=[eye])
    sols, path = solve_path(system, targets, ik_options(scn.model.solver), safety=rules)
    inside = np.flatnonzero(np.linalg.norm(targets.points - targets.points[k], axis=1) < 0.004)
    failed = [i for i, s in enumerate(sols) if not s.ok]
    assert set(inside) <= set(failed) and len(failed) < len(sols) // 2
    assert all(sols[i].reason == "keep_out" for i in failed)
    gaps = [g for g in path.gaps if g.reason == "keep_out"]
    assert any(g.k0 <= k < g.k1 for g in gaps)
    assert not path.ok[failed].any() and np.isnan(path.q[failed]).all()
    for seg in path.segments:  # the feasible runs skip the gap
        assert not any(seg.k0 <= i < seg.k1 for i in failed)
    # the samples kept: beams clear of the eye by the numpy geometry
    s = setup(system, keep=(eye,))
    for i in range(0, len(sols), 7):
        if sols[i].ok:
            beam = np.vstack([system.world_T_laser[:3, 3], sols[i].hits, sols[i].spot])
            assert not [h for h in hits(s, system, sols[i].q, beam) if h.check == "beam_keep_out"]


def test_planned_path_with_an_eye_checks_clean(tmp_path, curve) -> None:  # type: ignore[no-untyped-def]
    from planner.io.plan_file import plan_json
    from planner.plan.pipeline import run_scenario

    targets = curve[2]
    text = (REPO / "scenarios" / "curve_path.yaml").read_text()
    p = targets.points[len(targets) // 3]
    text += f"keep_out:\n  - {{name: eye, sphere: 0.003, world_T_object: {{xyz: {p.tolist()}}}}}\n"
    path = tmp_path / "curve_eye.yaml"
    path.write_text(text)
    out = run_scenario(path, progress=False)
    reasons = {s.reason for s in out.solutions if not s.ok}
    assert reasons == {"keep_out"}
    doc = json.loads(plan_json(out.doc))
    results = {r.name: r for r in check_plan(doc)}
    assert not results["safety"].findings and not results["trajectory safety"].findings
    assert results["trajectory safety"].figures["laser_on_samples"] > 100


def test_unsafe_path_nlp_result_falls_back_to_its_warm_start(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Three arms relay the beam to a square. A run whose NLP result breaks the rules at
    more samples than its warm start keeps the warm start: the clearance step here reports
    every NLP sample of the run unsafe (what the path NLP without its posture term found,
    arm2's last beam through its own base; the NLP alone now finds a safe result, so a
    check conditioned on it never ran), and the run keeps its (safe) warm start, every
    sample solved and clear by the numpy geometry."""
    import planner.path.solve as path_solve
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.plan.scenario_planner import ik_options, solve_path
    from tests.planner.verify.test_plan_check_agreement import N3_SQUARE

    (tmp_path / "n3.yaml").write_text(N3_SQUARE)
    scn = load_scenario(tmp_path / "n3.yaml")
    system = system_from_scenario(scn)
    targets = targets_from_scenario(scn, system)
    s = setup(system)
    clearance, reported = path_solve._clearance, []

    def every_sample_unsafe(ctx, safety, ks, *rest):  # type: ignore[no-untyped-def]
        q, seg, _ = clearance(ctx, safety, ks, *rest)
        reported.append(len(ks))
        return q, seg, len(ks)

    monkeypatch.setattr(path_solve, "_clearance", every_sample_unsafe)
    sols, path = solve_path(system, targets, ik_options(scn.model.solver),
                            safety=Safety.from_scenario(scn, system))  # fmt: skip
    assert reported, "no run of the path NLP reached the safety rules"
    runs = [seg for seg in path.segments if seg.k1 - seg.k0 >= 2]
    assert len(runs) == len(reported) and sum(reported) == sum(g.k1 - g.k0 for g in runs)
    assert all(seg.status.startswith("warm_start (NLP result unsafe") for seg in runs), runs
    assert all(sol.ok for sol in sols)
    beams = [np.vstack([system.world_T_laser[:3, 3], sol.hits, sol.spot]) for sol in sols]
    assert not any(hits(s, system, sol.q, beam) for sol, beam in zip(sols, beams, strict=True))
