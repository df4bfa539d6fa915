"""Client: spot samples count for target k only at rest on q_k; mean mapped to the world."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

from planner.model.transforms import look_at, transform_points
from planner.service import client as cl
from planner.service.client import PlanClient, Recorder, make_request, measured_spots
from tests.planner.service.plans import as_plan


def rest_at(rec: Recorder, q: np.ndarray, t0: float, t1: float, rate: float = 500.0) -> None:
    """Joint states of arm0 resting at ``q`` from ``t0`` to ``t1`` (stamps, s)."""
    for t in np.arange(t0, t1, 1.0 / rate):
        rec.on_joints("arm0", q, np.zeros(6), float(t))


def test_spots_are_assigned_to_the_target_the_robot_rests_on() -> None:
    world_T_camera = look_at([1.0, -0.5, 0.8], [0.0, 0.0, 0.0])
    q0, q1 = np.zeros(6), np.full(6, 0.1)
    plan = as_plan({
        "scenario": {"system": {"camera": {"world_T_camera": {"matrix": world_T_camera.tolist()}}}},
        "solutions": [
            {"status": "ok", "q": {"arm0": q0.tolist()}},
            {"status": "failed", "q": {}},
            {"status": "ok", "q": {"arm0": q1.tolist()}},
        ],
    })  # fmt: skip
    rec = Recorder()
    since = time.monotonic()
    t = 1000.0  # the drivers' and the camera's stamps (UNIX s)
    rest_at(rec, q0, t, t + 1.0)
    rec.on_spot(np.array([9.0, 9.0, 9.0]), t + 0.5 * cl.SETTLE)  # at rest for < SETTLE: ignored
    p_cam = [np.array([0.01, 0.02, 0.5]), np.array([0.03, 0.02, 0.5])]
    for k, p in enumerate(p_cam):
        rec.on_spot(p, t + 0.5 + 0.1 * k)
    rec.on_joints("arm0", q0 + 0.05, np.full(6, 0.2), t + 1.0)  # moving: spots ignored
    rec.on_spot(np.array([7.0, 7.0, 7.0]), t + 1.0)
    rest_at(rec, q1 + 0.5 * cl.AT_TARGET_Q, t + 1.01, t + 2.0)
    rec.on_spot(np.array([0.0, 0.0, 0.4]), t + 1.5)
    out = measured_spots(plan, rec, since)
    np.testing.assert_allclose(out[0], transform_points(world_T_camera, [[0.02, 0.02, 0.5]])[0])
    assert out[1] is None
    np.testing.assert_allclose(out[2], transform_points(world_T_camera, [[0.0, 0.0, 0.4]])[0])
    assert measured_spots(plan, rec, time.monotonic() + 1) == [None, None, None]


def test_a_spot_is_placed_on_the_joints_of_its_capture_not_of_its_arrival() -> None:
    """Frames arrive late (a loaded machine): one taken on the way to q1 that arrives while
    the arm rests on q1 is not q1's; one taken at rest on q0 that arrives after the arm left
    is q0's; a spot captured after the newest joint state waits for it."""
    q0, q1 = np.zeros(6), np.full(6, 0.1)
    rec = Recorder()
    t = 1000.0
    rest_at(rec, q0, t, t + 0.5)
    for k, tk in enumerate(np.linspace(t + 0.5, t + 0.6, 11)):  # moving q0 -> q1
        rec.on_joints("arm0", q0 + (q1 - q0) * k / 10, np.full(6, 1.0), float(tk))
    rest_at(rec, q1, t + 0.602, t + 1.0)
    rec.on_spot(np.array([0.0, 0.0, 0.5]), t + 0.45)  # taken at rest on q0, arrives now
    rec.on_spot(np.array([0.0, 0.0, 0.6]), t + 0.55)  # taken on the way
    rec.on_spot(np.array([0.0, 0.0, 0.7]), t + 0.62)  # on q1, but not settled for SETTLE
    rec.on_spot(np.array([0.0, 0.0, 0.8]), t + 0.9)  # settled on q1
    rec.on_spot(np.array([0.0, 0.0, 0.9]), t + 1.2)  # not reached by the joint states yet
    placed = [(float(s.p_camera[2]), s.rest, float(s.q["arm0"][0])) for s in rec.spots]
    assert placed == [(0.5, True, 0.0), (0.6, False, 0.05), (0.7, False, 0.1), (0.8, True, 0.1)]
    assert len(rec.pending) == 1
    rest_at(rec, q1, t + 1.0, t + 1.3)
    assert rec.spots[-1].p_camera[2] == 0.9 and rec.spots[-1].rest and rec.spots[-1].t == t + 1.2
    assert not rec.pending
    assert rec.rest_time("arm0") == pytest.approx(1.3 - 0.602, abs=3e-3)


def test_a_spot_captured_after_a_silent_robot_is_placed_late_and_not_at_rest() -> None:
    rec = Recorder()
    rest_at(rec, np.zeros(6), 1000.0, 1000.5)
    rec.on_spot(np.array([0.0, 0.0, 0.5]), 1001.0)  # the driver went silent at 1000.5
    assert not rec.spots
    rec.pending[0] = (rec.pending[0][0] - 2 * cl.PLACE_WAIT, *rec.pending[0][1:])
    rec.on_spot(np.array([0.0, 0.0, 0.6]), 1001.1)  # placed the first; this one waits
    assert [(float(s.p_camera[2]), s.rest) for s in rec.spots] == [(0.5, False)]
    assert len(rec.pending) == 1


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
    return as_plan({"id": "r1", "execution": "accepted", "robots": ["arm0"],
                    "joint_names": {"arm0": [f"j{k}" for k in range(6)]},
                    "trajectory": {"t": [0.0, duration], "q": q, "qd": q, "qdd": q}}).to_document()  # fmt: skip


def test_execute_stops_waiting_when_a_driver_stops_this_trajectory() -> None:
    # a 60 s trajectory the driver stops after 0.2 s: the client returns long before 60 s
    t0 = time.monotonic()
    client = fake_client(moving_plan(60.0), ("arm0", "r1"))
    client.execute({"points": []}, 60.0, settle=0.0)
    assert time.monotonic() - t0 < 30.0
    assert client.interruption == "arm0: stop"  # `request --execute` exits 1 with it
    # a fault of another request does not end the wait: it lasts the whole trajectory
    t0 = time.monotonic()
    fake_client(moving_plan(0.6), ("arm0", "r0")).execute({"points": []}, 0.5, settle=0.0)
    assert time.monotonic() - t0 >= 0.6  # no joint state: at rest once the duration is over


def test_execute_names_robots_that_never_came_to_rest_at_the_end() -> None:
    client = fake_client(moving_plan(0.1), None)
    client.recorder.on_joints("arm0", np.zeros(6), np.full(6, 0.5), 0.0)  # still moving
    client.execute({"points": []}, 0.2, settle=0.0)
    assert client.interruption is not None and "did not come to rest" in client.interruption
