"""A reply's typed reports (closed loop, tracking) and a plan's typed scenario reads: every
row shape a closed-loop run writes reads back to the same JSON, statuses and reasons are
enums, an unknown one is a one-line error naming its key path, and so is an unknown
segment kind. (Real closed-loop replies round-trip in tests/planner/service/test_closed_loop.py.)"""

from __future__ import annotations

import copy
import json
import math
from typing import Any

import numpy as np
import pytest

from planner.errors import InputError
from planner.io.plan import ClosedLoopReport, Plan, SegmentKind, TrackingReport
from planner.model.status import Interruption, Reason, ServoStatus
from schemas.common import FieldError
from tests.planner.io.test_plan import assert_an_unknown_value_names_its_field, small_doc

SERVED = {"iterations": 2, "frames": 9, "time": 0.75, "measured_error_before": 0.004,
          "measured_error_after": 0.0001, "errors": [0.004, None, 0.0001],
          "measured_spot": [0.1, 0.2, 0.3]}  # fmt: skip


def closed_loop() -> dict[str, Any]:
    """A closed-loop report with a row of every shape the run writes, keys in its order."""
    return {
        "tolerance": 0.0003, "frames_per_measurement": 3, "dwell": 0.2, "moves": 5,
        "dropped": {"low_confidence": 1, "implausible": 0}, "frame": "camera",
        "targets": [
            {"id": 0, "dwell": 0.2, "treated": True, "status": "converged", **SERVED,
             "reason": None, "detail": None, "q": {"arm0": [0.5, -0.5]},
             "target_camera": [0.0, 0.0, 0.8], "measured_spot_camera": [0.0, 0.001, 0.8],
             "measured_error_camera": 0.001},
            {"id": 1, "dwell": 0.0, "treated": False, "status": "refused", **SERVED,
             "reason": "keep_out", "detail": "beam 2 mm inside eye", "q": {"arm0": [0.1, 0.2]},
             "target_camera": [0.0, 0.1, 0.8]},
            {"id": 2, "dwell": 0.0, "treated": False, "status": "not_planned",
             "target_camera": [0.0, 0.2, 0.8]},
            {"id": 3, "dwell": 0.0, "treated": False, "status": "rejected",
             "reason": "execution", "detail": "arm0: start away", "target_camera": [0.1, 0.0, 0.8]},
            {"id": 4, "status": "not_executed", "dwell": 0.0, "target_camera": [0.2, 0.0, 0.8]},
            {"id": 5, "dwell": 0.0, "treated": False, "status": "aborted", "reason": "stop",
             "detail": "stopped", "target_camera": [0.3, 0.0, 0.8]},
        ],
    }  # fmt: skip


def reply(**sections: Any) -> dict[str, Any]:
    doc = small_doc()
    for key in ("closed_loop", "tracking"):  # their place among the reply's keys
        if key in sections:
            doc[key] = sections[key]
    tail = {k: doc.pop(k) for k in ("execution_unanswered", "execution", "execution_reason")
            if k in doc}  # fmt: skip
    return doc | tail


def test_every_closed_loop_row_reads_back_to_the_same_json() -> None:
    doc = reply(closed_loop=closed_loop())
    original = copy.deepcopy(doc)
    plan = Plan.from_document(doc)
    assert json.dumps(plan.to_document()) == json.dumps(original) and doc == original
    report = plan.closed_loop
    assert isinstance(report, ClosedLoopReport) and report.converged == 1
    rows = report.targets
    assert [r.status for r in rows] == [ServoStatus.CONVERGED, ServoStatus.REFUSED,
                                        ServoStatus.NOT_PLANNED, ServoStatus.REJECTED,
                                        ServoStatus.NOT_EXECUTED, ServoStatus.ABORTED]  # fmt: skip
    assert [r.reason for r in rows] == [None, Reason.KEEP_OUT, None, Interruption.EXECUTION,
                                        None, Interruption.STOP]  # fmt: skip
    assert [r.treated for r in rows] == [True, False, False, False, None, False]
    run = rows[0].servo
    assert run is not None and rows[2].servo is None
    assert run.error_after == 1e-4 and math.isnan(run.errors[1]) and run.q["arm0"].shape == (2,)
    assert rows[0].error_camera == 0.001 and rows[1].spot_camera is None
    spots = report.spots(len(rows))
    np.testing.assert_array_equal(spots[0], [0.1, 0.2, 0.3])
    assert spots[2] is None
    with pytest.raises(ValueError, match="read-only"):
        run.errors[0] = 1.0


def test_a_tracking_report_reads_back_to_the_same_json() -> None:
    tracking = {"stream": "phantom", "duration": None, "tolerance": 0.0005, "rate": 500.0,
                "camera_correction": "off: targets in the world frame"}  # fmt: skip
    doc = reply(tracking=tracking)
    plan = Plan.from_document(doc)
    assert plan.tracking == TrackingReport(
        "phantom", None, 5e-4, 500.0, tracking["camera_correction"]
    )
    assert json.dumps(plan.to_document()) == json.dumps(doc)


@pytest.mark.parametrize(
    ("where", "value", "message"),
    [
        (("closed_loop", "targets", 1, "status"), "done",
         "closed_loop.targets.1.status: unknown servo status 'done' (converged, "),
        (("closed_loop", "targets", 3, "reason"), "tired",
         "closed_loop.targets.3.reason: unknown reason 'tired' (unreachable, "),
        (("trajectory", "segments", 0, "kind"), "hover",
         "trajectory.segments.0.kind: unknown segment kind 'hover' (approach, move, run_in, "
         "path, run_out, dwell)"),
    ],
)  # fmt: skip
def test_an_unknown_status_reason_or_kind_names_its_key_path(
    where: tuple[str | int, ...], value: str, message: str
) -> None:
    assert_an_unknown_value_names_its_field(reply(closed_loop=closed_loop()), where, value, message)


def test_a_missing_report_key_names_its_key_path() -> None:
    doc = reply(tracking={"stream": "s", "duration": 1.0, "tolerance": 5e-4, "rate": 500.0})
    with pytest.raises(FieldError, match=r"^tracking\.camera_correction: required$"):
        Plan.from_document(doc)


def test_segment_kinds_are_enums() -> None:
    plan = Plan.from_document(small_doc())
    assert plan.trajectory is not None
    assert plan.trajectory.segments[0].kind is SegmentKind.APPROACH


def test_the_resolved_scenario_reads_typed_and_names_a_bad_key() -> None:
    doc = small_doc()
    doc["scenario"] = {
        "name": "small",
        "system": {"laser": {"world_T_laser": {"matrix": np.eye(4).tolist()},
                             "gate": {"robot": "arm0", "output": 0}, "aim": "gate"},
                   "camera": {"world_T_camera": {"matrix": np.eye(4).tolist()},
                              "intrinsics": {"width": 2, "height": 2, "fx": 1.0, "fy": 1.0,
                                             "cx": 1.0, "cy": 1.0}}},
        "keep_out": [{"name": "eye", "sphere": 0.01, "attached_to": "phantom",
                      "world_T_object": {"matrix": np.eye(4).tolist()}}],
        "trajectory": {"spot_speed": 0.03},
    }  # fmt: skip
    scenario = Plan.from_document(doc).resolved
    assert scenario.name == "small" and scenario.trajectory.spot_speed == 0.03
    assert scenario.laser is not None and scenario.laser.gate is not None
    assert scenario.laser.gate.robot == "arm0"
    assert scenario.laser.aim == "gate" and scenario.safety.spot_uncertainty == 0.0
    assert [(o.name, o.attached_to) for o in scenario.keep_out] == [("eye", "phantom")]
    np.testing.assert_array_equal(scenario.world_T_camera, np.eye(4))
    doc["scenario"]["system"]["laser"]["gate"]["output"] = "two"
    with pytest.raises(InputError, match=r"scenario\.system\.laser\.gate\.output: expected"):
        _ = Plan.from_document(doc).resolved.laser
    assert Plan.from_document(small_doc()).resolved.world_T_camera is None
