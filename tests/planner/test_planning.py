"""Batch planning: plan.json shape (schema), metrics vs independent figures, failures."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from planner.ik import IKOptions
from planner.planning import plan_document, plan_points, plan_scenario
from planner.system import Targets
from schemas.plan import Plan
from tests.planner.ik import ik_systems as sy

SCENARIO = """\
name: test-n1
system:
  laser: {world_T_laser: {xyz: [0.60, -0.40, 0.30], rpy_deg: [0, -90, 0]}}
  robots:
    - name: arm0
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075], roi_margin: 0.01}
targets:
  grid: {center: [0.3, 0.3, 0.3], size: [0.1, 0.1, 0.1], n: [3, 3, 2]}
"""


def write_scenario(tmp: Path, text: str = SCENARIO) -> Path:
    path = tmp / "scn.yaml"
    path.write_text(text)
    return path


def test_plan_points_keeps_going_after_a_failure() -> None:
    system = sy.n1()
    pts = np.array([[0.3, 0.3, 0.3], [-3.0, -0.4, 0.3], [0.31, 0.3, 0.3]])
    sols = plan_points(system, Targets(pts), IKOptions())
    assert [s.status for s in sols] == ["ok", "failed", "ok"]
    assert sols[1].reason == "back_face"
    doc = plan_document(system, Targets(pts), sols, {"name": "t"})
    Plan.model_validate(doc)
    m = doc["metrics"]
    assert (m["n_targets"], m["n_ok"]) == (3, 2)
    assert m["error_max"] == max(sols[0].error, sols[2].error)
    assert m["extra"] == {"failed_back_face": 1}
    assert "q" not in doc["solutions"][1]
    np.testing.assert_allclose(doc["solutions"][2]["q"]["arm0"], sols[2].q)


def test_plan_scenario_document(tmp_path: Path) -> None:
    doc, system, _ = plan_scenario(write_scenario(tmp_path), progress=False)
    plan = Plan.model_validate(doc)
    assert len(plan.targets) == 18 and plan.metrics.n_ok == 18
    assert plan.robots == ["arm0"]
    assert plan.scenario["system"]["laser"]["world_T_laser"]["matrix"]
    errors = [s.error for s in plan.solutions if s.error is not None]
    assert max(errors) <= 1e-12
    assert plan.metrics.error_median == float(np.median(errors))
    # targets are the grid: 3 x 3 x 2 points spanning the 100 mm cube
    P = np.array([t.p for t in plan.targets])
    np.testing.assert_allclose(np.ptp(P, axis=0), [0.1, 0.1, 0.1])
    for sol in plan.solutions:
        np.testing.assert_allclose(sol.hits[0].p, np.asarray(sol.hits[0].p))
        assert np.all(np.abs(sol.hits[0].uv) <= system.robots[0].mirror.roi_half)
