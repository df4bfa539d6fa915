"""Numpy trajectory check: limit detection, spot deviation, curve_path end to end."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from planner.verify.spot import trajectory_findings
from planner.verify.trajectory import point_deviation, spot_deviation
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "curve_path.yaml"


def _scenario_dict(system, rate, speed):
    robots = [{
        "name": r.name, "model": "ur5e", "world_T_base": {"matrix": r.world_T_base.tolist()},
        "mirror": {"flange_T_mirror": {"matrix": r.mirror.flange_T_mirror.tolist()}},
        "limits": {k: getattr(r.limits, k).tolist()
                   for k in ("lower", "upper", "velocity", "acceleration", "jerk")},
    } for r in system.robots]  # fmt: skip
    return {
        "system": {"laser": {"world_T_laser": {"matrix": system.world_T_laser.tolist()}},
                   "robots": robots},
        "targets": {"path": {"closed": False}},
        "trajectory": {"rate": rate, "spot_speed": speed},
    }  # fmt: skip


@pytest.fixture(scope="module")
def plan():
    from planner.ik.closed_form import ClosedForm
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.path.solve import plan_path
    from planner.path.timing import path_trajectory

    loaded = load_scenario(SCENARIO)
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    assert targets.normals is not None
    res = plan_path(system, targets, seeder=ClosedForm(system))
    speed = loaded.model.trajectory.spot_speed
    traj = path_trajectory(system, [(res.q, res.arc)], spot_speed=speed, rate=500.0)
    return {
        "scenario": _scenario_dict(system, 500.0, speed),
        "targets": [{"id": i, "p": p.tolist(), "n": n.tolist()}
                    for i, (p, n) in enumerate(zip(targets.points, targets.normals, strict=True))],
        "trajectory": traj.to_plan_dict(system),
    }  # fmt: skip


def test_curve_path_meets_goals(plan):
    found = {f.code: f for f in trajectory_findings(plan)}
    assert not [f for f in found.values() if f.severity != "info"], found
    assert found["path_deviation"].value <= 5e-5  # issue goal: 0.05 mm
    assert abs(found["path_duration"].value / found["path_duration"].bound - 1) < 0.1


def test_violations_are_found(plan):
    bad = copy.deepcopy(plan)
    q = np.asarray(bad["trajectory"]["q"]["arm0"])
    i = len(q) - 400  # inside the path segment
    q[i, 2] += 1e-3  # a 1 mrad kink: jerk ~ 3e-3 * 500^3, and the spot leaves the line
    bad["trajectory"]["q"]["arm0"] = q.tolist()
    codes = {f.code for f in trajectory_findings(bad) if f.severity == "error"}
    assert {"jerk", "path_deviation"} <= codes
    bad["trajectory"]["t"][5] += 1e-3
    assert "time_grid" in {f.code for f in trajectory_findings(bad) if f.severity == "error"}


def test_point_and_polyline_deviation_known_geometry():
    # rays straight down (-z) from above; targets on the z = 0 plane
    P = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0]])
    p = np.array([[0.05, 0.003, 1.0], [0.1 + 0.002, 0.05, 2.0], [0.0, 0.0, 0.5]])
    v = np.tile([0.0, 0.0, -1.0], (3, 1))
    np.testing.assert_allclose(spot_deviation(p, v, P, None, False), [0.003, 0.002, 0.0],
                               atol=1e-15)  # fmt: skip
    # to the nearest vertex: (0.05, 0.003) is 0.05 from both ends of the first edge
    np.testing.assert_allclose(point_deviation(p, v, P, None), [np.hypot(0.05, 0.003),
                               np.hypot(0.002, 0.05), 0.0], atol=1e-15)  # fmt: skip
    # a tilted ray meets the target's plane (normal +z) away from its closest approach
    tilt = np.array([[0.0, 0.0, 1.0]])
    d = np.array([[np.sin(0.1), 0.0, -np.cos(0.1)]])
    normals = np.tile([0.0, 0, 1], (3, 1))
    assert point_deviation(tilt, d, P[:1], normals[:1])[0] == pytest.approx(np.tan(0.1))


def test_urdf_robots_are_not_checked_with_the_ur_model(plan):
    doc = copy.deepcopy(plan)
    robot = doc["scenario"]["system"]["robots"][0]
    robot.pop("model")
    robot["urdf"] = "/somewhere/calibrated_ur5e.urdf"
    found = {f.code: f for f in trajectory_findings(doc)}
    assert found["model_unchecked"].severity == "warning"
    assert "path_deviation" not in found  # no spot check without a numpy model
    assert found["velocity"].severity == "info"  # limits are still checked


def test_arrival_checked_at_the_end_of_the_approach(plan):
    found = {f.code: f for f in trajectory_findings(plan)}
    assert found["arrival_deviation"].severity == "info"
    assert found["arrival_deviation"].value < 1e-8  # the approach ends on the first sample
    bad = copy.deepcopy(plan)
    seg = bad["trajectory"]["segments"][0]
    assert seg["kind"] == "approach"
    bad["trajectory"]["q"]["arm0"][round(seg["t1"] * 500.0)][3] += 2e-3
    found = {f.code: f for f in trajectory_findings(bad)}
    assert found["arrival_deviation"].severity == "error"


@pytest.mark.parametrize("kink", [None, 10, 600, -3])
def test_limits_checked_in_blocks_find_what_one_block_finds(plan, monkeypatch, kink):
    """The limit checks run a block of samples at a time (bounded memory for millions of
    samples): with blocks of 7 samples every finding, value and place is the one a single
    block gives, including a violation on a block's edge and a NaN."""
    from planner.verify import trajectory as vt

    bad = copy.deepcopy(plan)
    if kink is not None:
        q = np.asarray(bad["trajectory"]["q"]["arm0"])
        q[kink, 1] += 2e-3  # a kink near the start, in the middle, at the end
        qd = np.asarray(bad["trajectory"]["qd"]["arm0"])
        qd[kink + 1, 4] = np.nan if kink == 600 else qd[kink + 1, 4] + 0.1
        bad["trajectory"]["q"]["arm0"], bad["trajectory"]["qd"]["arm0"] = q.tolist(), qd.tolist()
    whole = [(f.code, f.severity, f.message, f.value) for f in vt.check_trajectory(bad)]
    monkeypatch.setattr(vt, "CHUNK_ROWS", 7)
    blocks = [(f.code, f.severity, f.message, f.value) for f in vt.check_trajectory(bad)]
    assert len(plan["trajectory"]["t"]) > 100 * 7
    assert blocks == whole
    if kink is not None:
        assert {"jerk", "velocity_declared"} <= {c for c, s, _, _ in whole if s == "error"}
