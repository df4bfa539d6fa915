"""The node's plan function re-verifies its solutions before it times the trajectory: a
solution the checks of ``beamrelay check`` reject is reported failed and never visited."""

from __future__ import annotations

import copy

import numpy as np

from planner.data import shipped_scenario
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
from planner.model.system import Targets
from planner.plan.scenario_planner import plan_points
from planner.service.handler import make_plan_fn


def test_a_solution_rejected_by_verification_is_not_in_the_trajectory() -> None:
    loaded = load_scenario(shipped_scenario("paper_n1.yaml"))
    system = system_from_scenario(loaded)
    points = targets_from_scenario(loaded, system).points[[0, 999]]
    targets = Targets(points, None, kind="points")
    q1, q2 = (np.asarray(s.q) for s in plan_points(system, targets))  # solved independently
    j = int(np.argmax(np.abs(q2 - q1)))
    assert abs(q2[j] - q1[j]) > 0.05
    # the resolved scenario (what verification reads) allows joint j only up to the midpoint
    # between the two solutions: the second one breaks it, the first one does not
    scenario = copy.deepcopy(resolved_scenario_dict(loaded))
    limits = scenario["system"]["robots"][0]["limits"]
    side = "upper" if q2[j] > q1[j] else "lower"
    limits[side][j] = float((q1[j] + q2[j]) / 2)
    plan = make_plan_fn(system, scenario)(targets, None, True).to_document()
    sols = plan["solutions"]
    assert sols[0]["status"] == "ok"
    assert sols[1]["status"] == "failed" and sols[1]["reason"] == "joint_limits"
    q = np.asarray(plan["trajectory"]["q"]["arm0"])
    dist = np.max(np.abs(q - q2), axis=1)  # every sample's distance to the rejected solution
    np.testing.assert_allclose(np.asarray(sols[0]["q"]["arm0"]), q1, atol=1e-9)
    assert np.min(np.max(np.abs(q - q1), axis=1)) < 1e-9  # the verified target is visited
    assert dist.min() > 0.02, f"the trajectory passes {dist.min():.4f} rad from it"
    assert plan["metrics"]["n_ok"] == 1


def test_a_request_dwell_overrides_the_scenarios_and_the_plan_says_so(tmp_path) -> None:
    from planner.verify.check import check_plan

    loaded = load_scenario(shipped_scenario("paper_n1.yaml"))
    system = system_from_scenario(loaded)
    points = targets_from_scenario(loaded, system).points[[0, 1, 2]]
    targets = Targets(points, None, kind="points")
    scenario = resolved_scenario_dict(loaded)
    plan_fn = make_plan_fn(system, scenario)
    plain = plan_fn(targets, None, True).to_document()
    dwelt = plan_fn(targets, None, True, dwell=0.25).to_document()
    spans = [s["t1"] - s["t0"] for s in dwelt["trajectory"]["segments"] if s["kind"] == "dwell"]
    assert len(spans) == 3 and np.allclose(spans, 0.25, atol=1.5 / 500)  # one sample at 500 Hz
    assert dwelt["scenario"]["trajectory"]["dwell"] == 0.25
    assert plain["scenario"]["trajectory"]["dwell"] == scenario["trajectory"]["dwell"]
    assert dwelt["trajectory"]["t"][-1] > plain["trajectory"]["t"][-1] + 0.7
    assert not [f for r in check_plan(dwelt, tmp_path) for f in r.findings]
