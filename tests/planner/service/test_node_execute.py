"""``execute`` against fake robot drivers written with plain zenoh: the reply says whether
the driver accepted the trajectory (its reason if not, a timeout if it is silent), carries the
request id, and the next trajectory starts where the robot will be when it begins."""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
import pytest

from planner.model.system import System
from planner.service.execution import ACK_TIMEOUT
from planner.service.node import PlannerNode, RequestHandler, make_plan_fn
from tests.drivers.conftest import wait_for
from tests.planner.raw_zenoh import Inbox, ask
from tests.planner.service.fake_driver import PREFIX, REJECTION, FakeDriver, NodeRig, NodeRigFactory
from tests.planner.service.test_node import reachable_targets, system_with_camera


@pytest.fixture(scope="module")
def system() -> System:
    return system_with_camera()


@pytest.fixture
def rig(system: System, node_rig: NodeRigFactory) -> NodeRig:
    def short_margin(node: PlannerNode) -> None:
        node.tracks.margin = 0.2

    robot = system.robots[0]
    return node_rig(RequestHandler(system, make_plan_fn(system, {})), robot.home + 0.05,
                    short_margin)  # fmt: skip


def execute(client: Any, points: np.ndarray, rid: str) -> dict[str, Any]:
    body = {"schema": "beamrelay.request/1", "id": rid, "points": points.tolist(),
            "execute": True}  # fmt: skip
    ok, reply = ask(client, f"{PREFIX}/plan", json.dumps(body).encode())
    plan = json.loads(reply)
    assert ok, plan
    return dict(plan)


def duration(traj: dict[str, Any]) -> float:
    return float(traj["t"][-1])


def test_accepted_reply_carries_ids_and_replans_from_the_running_trajectory(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver]
) -> None:
    node, client, fake = rig
    beats = Inbox(client, f"{PREFIX}/heartbeat")
    wait_for(lambda: len(beats.bodies()) > 5, 5.0, "heartbeats")
    q_meas = fake.q
    p1, p2, p3 = (reachable_targets(system, 1, seed=s) for s in (11, 12, 13))
    plan1 = execute(client, p1, "first")
    plan2 = execute(client, p2, "second")  # sent while the first still plays
    assert [plan1["execution"], plan2["execution"]] == ["accepted", "accepted"]
    assert plan1["execution_reason"] is None and plan2["id"] == "second"
    t1, t2 = fake.trajectories
    session = beats.bodies()[-1]["session"]
    assert (t1["id"], t2["id"]) == ("first", "second")
    assert t1["session"] == t2["session"] == session == node.session_id
    np.testing.assert_allclose(t1["q"][0], q_meas, atol=1e-9)  # from the measured state
    np.testing.assert_allclose(t2["q"][0], t1["q"][-1], atol=1e-9)  # from where t1 ends
    assert np.max(np.abs(np.subtract(t1["q"][-1], q_meas))) > 0.05
    # once both have played (+ the margin), the next one starts from the measured state
    time.sleep(duration(t1) + duration(t2) + node.tracks.margin + 0.1)
    plan3 = execute(client, p3, "third")
    assert plan3["execution"] == "accepted"
    np.testing.assert_allclose(fake.trajectories[2]["q"][0], q_meas, atol=1e-9)
    seqs = [b["seq"] for b in beats.bodies()]
    beats.close()
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # nothing lost, in order


def test_rejected_reply_names_the_robot_and_the_driver_reason(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver]
) -> None:
    _, client, fake = rig
    fake.behaviour = "reject"
    plan = execute(client, reachable_targets(system, 1, seed=21), "r1")
    assert plan["id"] == "r1" and plan["execution"] == "rejected"
    assert plan["execution_reason"] == f"arm0: {REJECTION}"
    # a rejected trajectory does not move the robot: the next one starts at the measured state
    fake.behaviour = "accept"
    plan = execute(client, reachable_targets(system, 1, seed=22), "r2")
    assert plan["execution"] == "accepted"
    np.testing.assert_allclose(fake.trajectories[-1]["q"][0], fake.q, atol=1e-9)


def test_silent_driver_is_a_rejection_after_the_timeout(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver]
) -> None:
    """A driver too busy to answer in time may still accept later: the reply says rejected,
    so a stop goes out with it and the driver refuses the trajectory it is still parsing."""
    _, client, fake = rig
    fake.behaviour = "silent"
    stops: list[bytes] = []
    sub = client.declare_subscriber(f"{PREFIX}/stop", lambda s: stops.append(s.payload.to_bytes()))
    t0 = time.monotonic()
    plan = execute(client, reachable_targets(system, 1, seed=31), "s1")
    waited = time.monotonic() - t0
    assert plan["execution"] == "rejected" and plan["id"] == "s1"
    assert plan["execution_reason"] == (
        f"no answer from arm0 within {ACK_TIMEOUT:g} s; stop sent, so a late acceptance does "
        "not move"
    )
    assert plan["execution_unanswered"] == ["arm0"]  # not heard, so not known to be refused
    assert waited >= ACK_TIMEOUT
    assert len(fake.trajectories) == 1 and fake.trajectories[0]["id"] == "s1"
    deadline = time.monotonic() + 5.0
    while not stops and time.monotonic() < deadline:
        time.sleep(0.01)
    sub.undeclare()
    assert len(stops) == 1 and b"request s1" in stops[0]


@pytest.mark.parametrize("halt", ["stop message", "braking status", "stop garbage"])
def test_a_halted_robot_is_replanned_from_its_measured_state(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver], halt: str
) -> None:
    node, client, fake = rig
    execute(client, reachable_targets(system, 1, seed=41), "h1")
    assert node.tracks.running_end("arm0") is not None
    if halt == "braking status":
        fake.status("braking", "h1")
    elif halt == "stop message":
        client.put(f"{PREFIX}/stop", json.dumps({"schema": "beamrelay.stop/1", "t": 0.0}))
    else:
        client.put(f"{PREFIX}/stop", b"\xff not even json")
    wait_for(lambda: node.tracks.running_end("arm0") is None, 5.0, "track forgotten")
    execute(client, reachable_targets(system, 1, seed=42), "h2")
    np.testing.assert_allclose(fake.trajectories[-1]["q"][0], fake.q, atol=1e-9)


def test_an_old_status_does_not_forget_a_newer_trajectory(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver]
) -> None:
    node, client, fake = rig
    execute(client, reachable_targets(system, 1, seed=51), "n1")
    fake.status("stopped", "an-older-one")  # a status still naming a previous trajectory
    time.sleep(0.3)
    assert node.tracks.running_end("arm0") is not None


class _Gone:
    def undeclare(self) -> None:
        pass


@pytest.mark.parametrize("halt", ["braking", "fault", "protective stop", "token gone"])
def test_a_robot_halting_mid_execution_stops_every_robot(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver], halt: str
) -> None:
    node, client, fake = rig
    stops = Inbox(client, f"{PREFIX}/stop")
    execute(client, reachable_targets(system, 1, seed=61), "x1")
    t0 = time.monotonic()
    if halt == "token gone":
        fake._token.undeclare()
        fake._token = _Gone()
    elif halt == "protective stop":
        body = {"schema": "beamrelay.status/1", "robot": "arm0", "t": time.time(),
                "mode": "following", "protective_stop": True,
                "trajectory": {"id": "x1", "accepted": True, "t": time.time()}}  # fmt: skip
        client.put(f"{PREFIX}/arm0/status", json.dumps(body))
    else:
        fake.status(halt, "x1")
    wait_for(lambda: bool(stops.bodies()), 5.0, "stop published")
    waited = stops.times()[0] - t0
    stop = stops.bodies()[0]
    print(f"{halt}: stop published {1e3 * waited:.1f} ms after it")
    assert stop["source"] == "planner" and "arm0" in stop["reason"]
    assert "during an execution" in stop["reason"]
    assert node.tracks.running_end("arm0") is None
    time.sleep(0.2)
    assert len(stops.bodies()) == 1  # the other robots' braking statuses add no stop


def test_a_halt_after_the_motion_or_of_an_older_trajectory_stops_nothing(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver]
) -> None:
    node, client, fake = rig
    stops = Inbox(client, f"{PREFIX}/stop")
    execute(client, reachable_targets(system, 1, seed=71), "y1")
    fake.status("stopped", "an-older-one")
    time.sleep(0.3)
    assert node.tracks.running_end("arm0") is not None and stops.bodies() == []
    wait_for(lambda: node.tracks.running_end("arm0") is None, 30.0, "the motion over")
    fake.status("braking", "y1")
    time.sleep(0.3)
    assert stops.bodies() == []


def test_a_preview_is_timed_at_the_preview_rate_and_an_execution_at_the_full_rate(
    system: System, rig: tuple[PlannerNode, Any, FakeDriver]
) -> None:
    """A request for the trajectory without executing it (the console's preview) is timed at
    PREVIEW_RATE, the rate echoed in its scenario (a check of it uses the same grid); the
    same targets executed are planned again at the scenario's rate, and that is what the
    driver gets."""
    from planner.service.handler import PREVIEW_RATE
    from schemas.defaults import SERVO_RATE_HZ

    _, client, fake = rig
    points = reachable_targets(system, 3, seed=41)
    body = {"schema": "beamrelay.request/1", "id": "pv1", "points": points.tolist(),
            "trajectory": True}  # fmt: skip
    ok, reply = ask(client, f"{PREFIX}/plan", json.dumps(body).encode())
    preview = json.loads(reply)
    assert ok, preview
    np.testing.assert_allclose(np.diff(preview["trajectory"]["t"]), 1 / PREVIEW_RATE, rtol=1e-9)
    assert preview["scenario"]["trajectory"]["rate"] == PREVIEW_RATE < SERVO_RATE_HZ
    assert fake.trajectories == []  # nothing sent
    plan = execute(client, points, "ex1")
    assert plan["execution"] == "accepted"
    sent = fake.trajectories[-1]
    np.testing.assert_allclose(np.diff(sent["t"]), 1 / SERVO_RATE_HZ, rtol=1e-9)
    np.testing.assert_allclose(np.diff(plan["trajectory"]["t"]), 1 / SERVO_RATE_HZ, rtol=1e-9)
    # the same targets in about the same time: the preview shows the motion to be run
    assert abs(duration(preview["trajectory"]) - duration(plan["trajectory"])) < 0.05
