"""Client: spot samples count for target k only at rest on q_k; mean mapped to the world."""

from __future__ import annotations

import time

import numpy as np

from planner.model.transforms import look_at, transform_points
from planner.service import client as cl
from planner.service.client import Recorder, make_request, measured_spots


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
