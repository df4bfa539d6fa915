"""Client: spot samples count for target k only at rest on q_k; mean mapped to the world."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from planner.model.transforms import look_at, transform_points
from planner.service import client as cl
from planner.service.client import PlanClient, Recorder, make_request, measured_spots


def test_spots_are_assigned_to_the_target_the_robot_rests_on() -> None:
    world_T_camera = look_at([1.0, -0.5, 0.8], [0.0, 0.0, 0.0])
    q0, q1 = np.zeros(6), np.full(6, 0.1)
    plan = {
        "scenario": {"system": {"camera": {"world_T_camera": {"matrix": world_T_camera.tolist()}}}},
        "solutions": [
            {"status": "ok", "q": {"arm0": q0.tolist()}},
            {"status": "failed", "q": {}},
            {"status": "ok", "q": {"arm0": q1.tolist()}},
        ],
    }
    rec = Recorder()
    since = time.monotonic()
    rec.on_joints("arm0", q0, np.zeros(6))
    rec.on_spot(np.array([9.0, 9.0, 9.0]))  # at rest for less than SETTLE: ignored
    rec.rest_since["arm0"] -= 2 * cl.SETTLE
    p_cam = [np.array([0.01, 0.02, 0.5]), np.array([0.03, 0.02, 0.5])]
    for p in p_cam:
        rec.on_spot(p)
    rec.on_joints("arm0", q0 + 0.05, np.full(6, 0.2))  # moving: spots ignored
    rec.on_spot(np.array([7.0, 7.0, 7.0]))
    rec.on_joints("arm0", q1 + 0.5 * cl.AT_TARGET_Q, np.zeros(6))
    rec.rest_since["arm0"] -= 2 * cl.SETTLE
    rec.on_spot(np.array([0.0, 0.0, 0.4]))
    out = measured_spots(plan, rec, since)
    np.testing.assert_allclose(out[0], transform_points(world_T_camera, [[0.02, 0.02, 0.5]])[0])
    assert out[1] is None
    np.testing.assert_allclose(out[2], transform_points(world_T_camera, [[0.0, 0.0, 0.4]])[0])
    assert measured_spots(plan, rec, time.monotonic() + 1) == [None, None, None]


def test_make_request_matches_the_schema() -> None:
    from schemas.messages import TargetRequest

    req = make_request([[1, 2, 3]], frame="camera", normals=[[0, 0, 2]], path=False, request_id="a")
    msg = TargetRequest.model_validate(req)
    assert msg.id == "a" and msg.frame == "camera" and msg.normals == [[0.0, 0.0, 1.0]]


def test_the_client_waits_for_the_arm_to_rest_at_the_end_not_on_a_dwell() -> None:
    q_end = {"arm0": np.full(6, 0.3)}
    rec = Recorder()
    assert rec.rests_at(q_end)  # no joint state at all: nothing to wait for
    rec.on_joints("arm0", np.full(6, 0.1), np.zeros(6))  # resting on a target on the way
    assert not rec.rests_at(q_end)
    rec.on_joints("arm0", np.full(6, 0.3), np.full(6, 0.01))  # passing the end, moving
    assert not rec.rests_at(q_end)
    rec.on_joints("arm0", np.full(6, 0.3) + 0.5 * cl.AT_TARGET_Q, np.zeros(6))
    assert rec.rests_at(q_end)
    assert rec.rests_at({**q_end, "arm1": np.zeros(6)})  # arm1 never seen: arm0 at rest counts


def test_faults_are_kept_per_robot_with_the_trajectory_they_stopped() -> None:
    rec = Recorder()
    assert rec.fault_of("r1") is None
    rec.on_status("arm0", "r1", "planner heartbeat lost: silent for 108 ms")
    rec.on_status("arm1", "r0", "stopped by console")  # an older request's fault
    assert rec.fault_of("r1") == "arm0: planner heartbeat lost: silent for 108 ms"
    assert rec.fault_of("r0") == "arm1: stopped by console"
    rec.on_status("arm0", "r2", None)  # a new trajectory clears it
    assert rec.fault_of("r1") is None


def fake_client(plan: dict[str, Any], fault: tuple[str, str] | None) -> PlanClient:
    """A PlanClient without a bus: ``request`` answers ``plan`` and, 0.2 s later, the driver
    of ``fault[0]`` reports a fault on request ``fault[1]``."""
    client = PlanClient.__new__(PlanClient)
    client.recorder, client._watching = Recorder(), True

    def request(req: dict[str, Any], timeout: float) -> dict[str, Any]:
        if fault is not None:
            threading.Timer(0.2, client.recorder.on_status, (fault[0], fault[1], "stop")).start()
        return plan

    client.request = request  # type: ignore[method-assign]
    return client


def moving_plan(duration: float) -> dict[str, Any]:
    q = {"arm0": [[0.0] * 6, [1.0] * 6]}
    return {"id": "r1", "execution": "accepted", "solutions": [], "scenario": {},
            "trajectory": {"t": [0.0, duration], "q": q}}  # fmt: skip


def test_execute_stops_waiting_when_a_driver_stops_this_trajectory() -> None:
    # a 60 s trajectory the driver stops after 0.2 s: the client returns long before 60 s
    t0 = time.monotonic()
    fake_client(moving_plan(60.0), ("arm0", "r1")).execute({"points": []}, 60.0, settle=0.0)
    assert time.monotonic() - t0 < 30.0
    # a fault of another request does not end the wait: it lasts the whole trajectory
    t0 = time.monotonic()
    fake_client(moving_plan(0.6), ("arm0", "r0")).execute({"points": []}, 0.5, settle=0.0)
    assert time.monotonic() - t0 >= 0.6  # no joint state: at rest once the duration is over
