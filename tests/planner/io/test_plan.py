"""The frozen Plan and its one mapping to and from the plan.json document: the shipped
scenarios' plans go document -> Plan -> document unchanged (as json reads them, and as
plan.json text), a plan cannot be changed in place, and an unknown status is a one-line
error naming its field."""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.io.plan import Plan, Verdict
from planner.io.plan_file import plan_json, read_plan, write_plan
from planner.model.status import Reason, Status
from planner.plan.pipeline import run_scenario
from schemas.common import FieldError
from tests.paths import SCENARIOS

SHIPPED = ("paper_n1", "n2_relay", "curve_path")


@pytest.fixture(scope="module", params=SHIPPED)
def written(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """plan.json of a shipped scenario, as ``beamrelay plan`` writes it."""
    out = run_scenario(SCENARIOS / f"{request.param}.yaml", progress=False)
    path = tmp_path_factory.mktemp(request.param) / "plan.json"
    with path.open("w") as fh:
        write_plan(out.doc, fh)
    return path


def test_document_round_trip_is_exact(written: Path) -> None:
    doc = json.loads(written.read_text())
    original = copy.deepcopy(doc)
    plan = Plan.from_document(doc)
    assert plan.to_document() == original
    assert json.dumps(plan.to_document()) == json.dumps(original)  # key order too
    assert doc == original  # reading does not change the document


def test_file_round_trip_is_byte_identical(written: Path) -> None:
    plan = Plan.from_document(read_plan(written))
    assert plan_json(plan.to_document(arrays=True)) == written.read_text()


def test_fields_are_typed(written: Path) -> None:
    plan = Plan.from_document(read_plan(written))
    assert all(isinstance(s.status, Status) for s in plan.solutions)
    assert all(s.reason is None or isinstance(s.reason, Reason) for s in plan.solutions)
    assert plan.metrics.n_ok == plan.n_ok == sum(s.status is Status.OK for s in plan.solutions)
    assert plan.trajectory is not None
    traj = plan.trajectory
    assert traj.t.ndim == 1 and traj.laser_on.shape[1] == 2
    for robot in plan.robots:
        assert traj.q[robot].shape == (len(traj.t), len(plan.joint_names[robot]))
    assert plan.targets.p.shape == (len(plan.targets), 3)


def small_doc() -> dict[str, Any]:
    return {
        "schema": "beamrelay.plan/1", "scenario": {"name": "small"}, "robots": ["arm0"],
        "joint_names": {"arm0": ["j0", "j1"]},
        "targets": [{"id": 0, "p": [0.1, 0.2, 0.3], "n": None},
                    {"id": 1, "p": [0.0, 0.0, 1.0], "n": [0.0, 0.0, 1.0]}],
        "solutions": [
            {"target": 0, "status": "ok", "reason": None, "q": {"arm0": [0.5, -0.5]},
             "spot": [0.1, 0.2, 0.3], "error": 1e-12, "incidence": 0.1,
             "hits": [{"robot": "arm0", "p": [0.0, 0.0, 0.5], "uv": [0.0, 0.01]}],
             "solve_time": 0.001, "iterations": 3},
            {"target": 1, "status": "failed", "reason": "occluded", "solve_time": 0.002,
             "iterations": 7},
        ],
        "trajectory": {"t": [0.0, 0.5], "q": {"arm0": [[0.0, 0.0], [0.5, -0.5]]},
                       "qd": {"arm0": [[0.0, 0.0], [0.0, 0.0]]},
                       "qdd": {"arm0": [[0.0, 0.0], [0.0, 0.0]]},
                       "segments": [{"kind": "approach", "t0": 0.0, "t1": 0.5}],
                       "laser_on": [], "slowdowns": []},
        "trajectory_requested": True,
        "metrics": {"n_targets": 2, "n_ok": 1, "error_max": 1e-12, "error_median": 1e-12,
                    "solve_time_median": 0.001, "solve_time_p95": 0.001, "duration": 0.5,
                    "extra": {"failed_occluded": 1}},
        "id": "r1", "execution": "accepted", "execution_reason": None,
    }  # fmt: skip


def test_a_reply_round_trips() -> None:
    doc = small_doc()
    plan = Plan.from_document(doc)
    assert plan.execution is Verdict.ACCEPTED and plan.id == "r1"
    assert plan.solutions[1].reason is Reason.OCCLUDED and not plan.solutions[1].ok
    assert plan.targets.normal(0) is None
    np.testing.assert_array_equal(plan.targets.normal(1), [0.0, 0.0, 1.0])
    assert json.dumps(plan.to_document()) == json.dumps(doc)


def test_plan_is_frozen() -> None:
    plan = Plan.from_document(small_doc())
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.id = "other"  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.solutions[0].status = Status.FAILED  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        plan.solutions[0].q["arm0"][0] = 1.0
    assert plan.trajectory is not None
    with pytest.raises(ValueError, match="read-only"):
        plan.trajectory.t[0] = 1.0
    changed = dataclasses.replace(plan, id="other")
    assert (changed.id, plan.id) == ("other", "r1")


@pytest.mark.parametrize(
    ("where", "value", "message"),
    [
        (("solutions", 1, "status"), "done", "solutions.1.status: unknown status 'done' (ok, failed)"),
        (("solutions", 1, "reason"), "blocked", "solutions.1.reason: unknown reason 'blocked' ("),
        (("execution",), "maybe", "execution: unknown verdict 'maybe' (accepted, rejected)"),
    ],
)  # fmt: skip
def test_an_unknown_enum_names_its_field(
    where: tuple[str | int, ...], value: str, message: str
) -> None:
    assert_an_unknown_value_names_its_field(small_doc(), where, value, message)


def assert_an_unknown_value_names_its_field(
    doc: dict[str, Any], where: tuple[str | int, ...], value: str, message: str
) -> None:
    """``doc`` with ``value`` put at key path ``where`` reads as a one-line FieldError that
    starts with ``message`` and names ``where``."""
    parent: Any = doc
    for key in where[:-1]:
        parent = parent[key]
    parent[where[-1]] = value
    with pytest.raises(FieldError) as err:
        Plan.from_document(doc)
    text = str(err.value)
    assert text.startswith(message) and "\n" not in text
    assert err.value.loc == where


def test_a_missing_key_names_its_field() -> None:
    doc = small_doc()
    del doc["solutions"][0]["status"]
    with pytest.raises(FieldError, match=r"^solutions\.0\.status: required$"):
        Plan.from_document(doc)
