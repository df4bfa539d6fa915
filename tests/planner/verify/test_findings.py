"""One Finding type for every check of ``beamrelay check``, with the reason enum."""

from __future__ import annotations

import copy

import pytest

from planner.model.status import Reason
from planner.verify.check import check_plan
from planner.verify.findings import Finding
from planner.verify.spot import trajectory_findings


def test_trajectory_and_target_findings_are_one_type(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    sol = next(s for s in doc["solutions"] if s["status"] == "ok")
    sol["q"]["arm0"][2] = 10.0  # an elbow far beyond its limit
    doc["trajectory"]["t"] = [*doc["trajectory"]["t"][:-1], doc["trajectory"]["t"][-1] + 0.3]
    found = [f for r in check_plan(doc) for f in r.findings]
    assert found and all(type(f) is Finding for f in found)
    limits = [f for f in found if f.check == "joint limits"]
    assert limits and limits[0].reason is Reason.JOINT_LIMITS and limits[0].target is not None
    grid = [f for f in found if f.check == "trajectory limits" and f.code == "time_grid"]
    assert grid and grid[0].reason is None and grid[0].target is None
    assert all(type(f) is Finding for f in trajectory_findings(plan_doc))
    assert {f.severity for f in trajectory_findings(plan_doc)} <= {"info", "warning"}


@pytest.fixture(scope="module")
def plan_doc(tmp_path_factory: pytest.TempPathFactory) -> dict:  # type: ignore[type-arg]
    from planner.plan.pipeline import plan_scenario
    from tests.planner.plan.test_pipeline import write_scenario

    doc, _, _ = plan_scenario(write_scenario(tmp_path_factory.mktemp("f")), progress=False)
    return doc
