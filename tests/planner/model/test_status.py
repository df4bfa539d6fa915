"""Status and Reason: one enum each, the plan.json strings, never parsed back out of text."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.ik import Solution
from planner.model.status import Failure, Reason, Status
from planner.plan.document import solution_json
from schemas.plan import FAILURE_REASONS
from schemas.plan import Reason as SchemaReason
from schemas.plan import Solution as SchemaSolution
from schemas.plan import Status as SchemaStatus
from tests.planner.ik import ik_systems as sy


def test_enums_are_the_file_format() -> None:
    """One definition each: the plan schema validates with the enums the planner uses."""
    assert SchemaReason is Reason and SchemaStatus is Status
    assert SchemaSolution.model_fields["reason"].annotation == Reason | None
    assert [r.value for r in Reason] == list(FAILURE_REASONS)
    assert json.dumps([Status.OK, Reason.KEEP_OUT]) == '["ok", "keep_out"]'


@pytest.mark.parametrize("reason", list(Reason))
def test_every_reason_survives_the_plan_file(reason: Reason) -> None:
    system = sy.n1()
    sol = Solution.failed(reason, 0.01, 3, "closed_form", {"why": "test"})
    doc = json.loads(json.dumps(solution_json(system, 7, sol)))
    assert (doc["status"], doc["reason"]) == ("failed", reason.value)
    parsed = SchemaSolution.model_validate(doc)
    assert Reason(parsed.reason) is reason and Status(parsed.status) is Status.FAILED


def test_failure_keeps_reason_and_detail_apart() -> None:
    f = Failure(Reason.OUTSIDE_ROI, "ROI (constraint 1: -0.002 < 9e-07)")
    assert f.reason is Reason.OUTSIDE_ROI and not f.detail.startswith("outside_roi")
    assert str(f) == "outside_roi: ROI (constraint 1: -0.002 < 9e-07)"
    assert str(Failure(Reason.UNREACHABLE)) == "unreachable"


def test_solver_results_carry_enums() -> None:
    """Real failures: the IK's reason and a path sample's verdict are enums with their
    evidence beside them, not "reason: detail" strings."""
    from planner.beam.trace import trace_beam
    from planner.ik import BeamIK
    from planner.model.system import Targets
    from planner.path.nlp import PathOptions
    from planner.path.warm import PathContext

    system = sy.n1()
    sol = BeamIK(system).solve([-3.0, -0.4, 0.3])  # on the incoming beam, past the mirror
    assert sol.status is Status.FAILED and sol.reason is Reason.BACK_FACE
    target = trace_beam(system, system.home, np.zeros(3))
    p = target.hits[-1] + 0.5 * target.dirs[-1]  # a point the home configuration hits
    ctx = PathContext(system, Targets(p[None, :], None, kind="path"), PathOptions())
    q = system.home.copy()
    q[2] = system.upper[2] + 0.2  # beyond the elbow limit
    out = ctx.eval(0, q, ctx.plane(0, system.home))
    why = ctx.why(0, q, out[0], out[4])
    assert why is not None and why.reason in (Reason.JOINT_LIMITS, Reason.UNREACHABLE)
    assert not why.detail.startswith(str(why.reason))
