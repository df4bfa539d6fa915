"""``execute`` against fake robot drivers written with plain zenoh: the reply says whether
the driver accepted the trajectory (its reason if not, a timeout if it is silent), carries the
request id, and the next trajectory starts where the robot will be when it begins."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from planner.model.system import System
from planner.service.bus import Keys, open_session
from planner.service.heartbeat import BusAddress
from planner.service.node import PlannerNode, RequestHandler, make_plan_fn
from tests.drivers.conftest import free_port, wait_for
from tests.planner.raw_zenoh import Inbox, ask, raw_session
from tests.planner.service.test_node import reachable_targets, system_with_camera

PREFIX = "exectest"
REJECTION = "q[0]: starts 0.2000 rad from the current state on joint elbow (tolerance 0.01 rad)"


class FakeDriver:
    """A robot driver in plain zenoh: token, joint states at 100 Hz (fixed ``q``), and a
    verdict in its status on every trajectory (``accept``, ``reject`` or ``silent``)."""

    def __init__(self, session: Any, robot: str, names: list[str], q: np.ndarray) -> None:
        self.session, self.robot, self.names, self.q = session, robot, names, q
        self.behaviour = "accept"
        self.trajectories: list[dict[str, Any]] = []
        self._stop = threading.Event()
        self._token = session.liveliness().declare_token(f"{PREFIX}/alive/{robot}")
        self._sub = session.declare_subscriber(f"{PREFIX}/{robot}/trajectory", self._on_traj)
        self._thread = threading.Thread(target=self._publish_states, daemon=True)
        self._thread.start()

    def _publish_states(self) -> None:
        while not self._stop.wait(0.01):
            body = {"schema": "beamrelay.joint_state/1", "t": time.time(), "names": self.names,
                    "q": self.q.tolist(), "qd": [0.0] * len(self.names)}  # fmt: skip
            self.session.put(f"{PREFIX}/{self.robot}/joint_states", json.dumps(body))

    def _on_traj(self, sample: Any) -> None:
        msg = json.loads(sample.payload.to_bytes())
        self.trajectories.append(msg)
        if self.behaviour == "silent":
            return
        self.status("following", msg["id"], self.behaviour == "accept")

    def status(self, mode: str, trajectory_id: str | None, accepted: bool = True) -> None:
        ack = {"id": trajectory_id, "accepted": accepted, "t": time.time(),
               "reason": None if accepted else REJECTION}  # fmt: skip
        body = {"schema": "beamrelay.status/1", "robot": self.robot, "t": time.time(),
                "mode": mode, "trajectory": ack}  # fmt: skip
        self.session.put(f"{PREFIX}/{self.robot}/status", json.dumps(body))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sub.undeclare()
        self._token.undeclare()


@pytest.fixture(scope="module")
def system() -> System:
    return system_with_camera()


@pytest.fixture
def rig(system: System) -> Iterator[tuple[PlannerNode, Any, FakeDriver]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_session(listen=True, endpoint=endpoint)
    node = PlannerNode(RequestHandler(system, make_plan_fn(system, {})), hub, Keys(PREFIX),
                       bus=BusAddress(endpoint))  # fmt: skip
    node.tracks.margin = 0.2
    node.start()
    client, fake_side = raw_session(endpoint), raw_session(endpoint)
    robot = system.robots[0]
    fake = FakeDriver(fake_side, "arm0", list(robot.joint_names), robot.home + 0.05)
    try:
        wait_for(lambda: "arm0" in node.alive and node.joints.get("arm0") is not None, 20.0,
                 "fake driver seen by the node")  # fmt: skip
        yield node, client, fake
    finally:
        fake.close()
        client.close()
        fake_side.close()
        node.close()
        hub.close()


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
    _, client, fake = rig
    fake.behaviour = "silent"
    t0 = time.monotonic()
    plan = execute(client, reachable_targets(system, 1, seed=31), "s1")
    waited = time.monotonic() - t0
    assert plan["execution"] == "rejected" and plan["id"] == "s1"
    assert plan["execution_reason"] == "no answer from arm0 within 1 s"
    assert waited >= 1.0
    assert len(fake.trajectories) == 1 and fake.trajectories[0]["id"] == "s1"


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
