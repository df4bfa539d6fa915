"""Planner node over a real Zenoh bus (in process, private port): replies, errors, execute."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.bus.session import Keys, encode, open_session
from planner.model.system import Camera, Intrinsics, System
from planner.model.transforms import look_at
from planner.service.client import PlanClient, RequestError, make_request
from planner.service.node import PlannerNode, RequestHandler, make_plan_fn, trajectory_messages
from schemas.messages import JointTrajectory
from tests.conftest import make_system
from tests.drivers.conftest import free_port, wait_for
from tests.planner.service.plans import as_plan

PREFIX = "nodetest"


def system_with_camera() -> System:
    s = make_system(1)
    world_T_camera = look_at([1.0, -0.8, 0.9], [0.3, 0.0, 0.2])
    return System(
        s.world_T_laser,
        s.robots,
        Camera(world_T_camera, Intrinsics(848, 480, 430.0, 430.0, 424.0, 240.0)),
    )


def reachable_targets(system: System, k: int, seed: int = 0) -> np.ndarray:
    """Points 0.5 m down the home beam, spread by up to 2 cm (inside the closed form's reach)."""
    tr = BeamModel(system).trace(system.home)
    rng = np.random.default_rng(seed)
    return tr.hits[-1] + 0.5 * tr.dirs[-1] + rng.uniform(-0.02, 0.02, (k, 3))


@pytest.fixture(scope="module")
def system() -> System:
    return system_with_camera()


@pytest.fixture
def bus(system: System) -> Iterator[tuple[str, PlannerNode]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(listen=True, endpoint=endpoint)
    handler = RequestHandler(system, make_plan_fn(system, {"name": "node-test"}))
    node = PlannerNode(handler, session, Keys(PREFIX), driver_grace=0.0).start()
    yield endpoint, node
    node.close()
    session.close()


@pytest.fixture
def client(bus: tuple[str, PlannerNode]) -> Iterator[PlanClient]:
    with PlanClient(endpoint=bus[0], prefix=PREFIX) as c:
        assert c.wait_for_node("planner", 10.0)
        yield c


def check_plan(system: System, plan: dict[str, Any], points: np.ndarray) -> None:
    """Every solution puts the beam on its target (independent CasADi trace)."""
    model = BeamModel(system)
    assert len(plan["solutions"]) == len(points)
    for sol, tgt, p in zip(plan["solutions"], plan["targets"], points, strict=True):
        np.testing.assert_allclose(tgt["p"], p, atol=1e-12)
        assert sol["status"] == "ok", sol
        tr = model.trace(system.stack_q(sol["q"]), p)
        assert tr.valid and tr.error < 1e-8


def test_plan_reply_puts_spot_on_target(
    system: System, client: PlanClient, bus: tuple[str, PlannerNode]
) -> None:
    points = reachable_targets(system, 5)
    plan = client.request(make_request(points))
    check_plan(system, plan, points)
    assert plan["scenario"] == {"name": "node-test"} and plan["trajectory"] is None
    assert bus[1].served == 1


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        (b"{not json", "body", "invalid JSON"),
        (b"[" * 100_000 + b"]" * 100_000, "body", "nested too deeply"),
        (b" " * (5 * 1024 * 1024), "body", "exceeds"),
        (
            b'{"schema":"beamrelay.request/1","id":"a","points":[[NaN,0,0]]}',
            "points[0][0]",
            "finite",
        ),
        (b'{"schema":"beamrelay.request/1","id":"a","points":[[1,0]]}', "points[0]", ""),
        (
            b'{"schema":"beamrelay.request/1","id":"a","points":[[1,0,0]],"robots":["x"]}',
            "robots",
            "",
        ),
        (b'{"schema":"beamrelay.plan/1","id":"a","points":[[1,0,0]]}', "schema", ""),
        (b'{"schema":"beamrelay.request/1","id":"a","points":[]}', "points", ""),
        (
            b'{"schema":"beamrelay.request/1","id":"a","frame":"base","points":[[1,0,0]]}',
            "frame",
            "",
        ),
        (b'"just a string"', "body", ""),
    ],
)
def test_bad_requests_get_error_replies_naming_the_field(
    system: System, client: PlanClient, body: bytes, field: str, words: str
) -> None:
    ok, reply = client.request_raw(body)
    err = json.loads(reply)
    assert not ok and err["schema"] == "beamrelay.error/1"
    assert (err["field"] or "body") == field, err
    assert words in err["error"]
    # the node keeps serving
    points = reachable_targets(system, 1)
    check_plan(system, client.request(make_request(points)), points)


def test_execute_refused_while_driver_down_names_it(client: PlanClient) -> None:
    with pytest.raises(RequestError) as exc:
        client.request(make_request([[0.5, 0.0, 0.3]], execute=True, request_id="r1"))
    assert exc.value.reply == {
        "schema": "beamrelay.error/1",
        "id": "r1",
        "error": "robot driver down: arm0",
        "field": "execute",
    }


def test_execute_waits_for_drivers_still_starting_only_within_the_grace(system: System) -> None:
    """``beamrelay up`` then ``request --execute`` at once: the planner waits up to its
    driver grace for a driver never seen; a driver seen and gone is down at once."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(listen=True, endpoint=endpoint)
    handler = RequestHandler(system, make_plan_fn(system, {"name": "node-test"}))
    grace = 1.5
    node = PlannerNode(handler, session, Keys(PREFIX), driver_grace=grace).start()
    started = time.monotonic()
    driver = open_session(listen=False, endpoint=endpoint)
    try:
        with PlanClient(endpoint=endpoint, prefix=PREFIX) as c:
            assert c.wait_for_node("planner", 10.0)
            timer = threading.Timer(0.3, lambda: tokens.append(
                driver.liveliness().declare_token(Keys(PREFIX).alive("arm0"))))  # fmt: skip
            tokens: list[Any] = []
            timer.start()
            with pytest.raises(RequestError) as exc:
                c.request(make_request([[0.5, 0.0, 0.3]], execute=True), timeout=10)
            # the token came during the grace (not "driver down"); the joint state never did
            assert "no current joint state from arm0" in exc.value.reply["error"]
            assert time.monotonic() - started >= grace
            tokens[0].undeclare()
            wait_for(lambda: "arm0" not in node.alive, what="arm0 token gone")
            # seen, then gone: down at once (and after the grace anyway)
            with pytest.raises(RequestError) as exc:
                c.request(make_request([[0.5, 0.0, 0.3]], execute=True), timeout=10)
            assert exc.value.reply["error"] == "robot driver down: arm0"
    finally:
        driver.close()
        node.close()
        session.close()


def test_execute_refused_without_joint_states(bus: tuple[str, PlannerNode]) -> None:
    endpoint, node = bus
    driver = open_session(listen=False, endpoint=endpoint)
    token = driver.liveliness().declare_token(Keys(PREFIX).alive("arm0"))
    try:
        wait_for(lambda: "arm0" in node.alive, what="arm0 token")
        with PlanClient(endpoint=endpoint, prefix=PREFIX) as c, pytest.raises(RequestError) as exc:
            c.request(make_request([[0.5, 0.0, 0.3]], execute=True))
        assert exc.value.reply["field"] == "execute"
        assert "no current joint state from arm0" in exc.value.reply["error"]
    finally:
        token.undeclare()
        driver.close()
    wait_for(lambda: "arm0" not in node.alive, what="arm0 token gone")


def test_several_clients_at_once(system: System, bus: tuple[str, PlannerNode]) -> None:
    results: dict[int, list[tuple[np.ndarray, dict[str, Any]]]] = {}
    errors: list[BaseException] = []

    def run(i: int) -> None:
        try:
            with PlanClient(endpoint=bus[0], prefix=PREFIX) as c:
                assert c.wait_for_node("planner")
                out = []
                for j in range(5):
                    pts = reachable_targets(system, 1 + (i + j) % 3, seed=10 * i + j)
                    out.append((pts, c.request(make_request(pts), timeout=30)))
                results[i] = out
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors
    assert sorted(results) == [0, 1, 2, 3]
    for out in results.values():
        for pts, plan in out:
            check_plan(system, plan, pts)
    assert bus[1].served == 20


def test_targets_topic_publishes_plan_and_errors(
    system: System, client: PlanClient, bus: tuple[str, PlannerNode]
) -> None:
    got: list[dict[str, Any]] = []
    sub = client.session.declare_subscriber(
        Keys(PREFIX).plans, lambda s: got.append(json.loads(s.payload.to_bytes()))
    )
    time.sleep(0.3)  # let the subscription reach the node
    points = reachable_targets(system, 2, seed=3)
    client.session.put(Keys(PREFIX).targets, encode(make_request(points)))
    client.session.put(Keys(PREFIX).targets, b'{"id": 7}')
    wait_for(lambda: len(got) == 2, what="two publications on plans")
    sub.undeclare()
    check_plan(system, got[0], points)
    assert got[1]["schema"] == "beamrelay.error/1" and got[1]["field"] == "id"


def test_liveliness_token_follows_the_node(system: System) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(listen=True, endpoint=endpoint)
    node = PlannerNode(RequestHandler(system, make_plan_fn(system, {})), session, Keys(PREFIX))
    with PlanClient(endpoint=endpoint, prefix=PREFIX) as c:
        assert not c.wait_for_node("planner", 0.5)
        node.start()
        assert c.wait_for_node("planner", 10.0)
        node.close()
        time.sleep(0.3)
        assert not c.wait_for_node("planner", 0.5)
    session.close()


def test_trajectory_messages_split_per_robot() -> None:
    t = [0.0, 0.002, 0.002, 0.004]  # a repeated time (segment boundary) is dropped
    q = [[0.1 * k] * 6 for k in range(4)]
    plan = {
        "robots": ["arm0"],
        "joint_names": {"arm0": [f"j{i}" for i in range(6)]},
        "trajectory": {"t": t, "q": {"arm0": q}, "qd": {"arm0": q}, "qdd": {"arm0": q}},
    }
    msg = JointTrajectory.model_validate_json(trajectory_messages(as_plan(plan))["arm0"])
    assert msg.t == [0.0, 0.002, 0.004]
    assert msg.q == [q[0], q[1], q[3]] and msg.names == plan["joint_names"]["arm0"]


def test_execute_moves_the_sim_arm_from_its_current_state(
    system: System, bus: tuple[str, PlannerNode]
) -> None:
    from drivers.robot.node import RobotNode
    from drivers.robot.sim import SimRobot

    endpoint, node = bus
    robot = system.robots[0]
    q_now = robot.home + 0.05  # the arm is not at the scenario's home
    session = open_session(listen=False, endpoint=endpoint)
    sim = SimRobot(robot.joint_names, q_now, robot.limits)
    driver = RobotNode(session, Keys(PREFIX), "arm0", sim, robot.limits).start()
    trajs: list[JointTrajectory] = []
    try:
        with PlanClient(endpoint=endpoint, prefix=PREFIX) as c:
            sub = c.session.declare_subscriber(
                Keys(PREFIX).trajectory("arm0"),
                lambda s: trajs.append(JointTrajectory.model_validate_json(s.payload.to_bytes())),
            )
            wait_for(lambda: driver.planner_alive and "arm0" in node.alive, what="both alive")
            wait_for(lambda: node.joints.get("arm0") is not None, what="joint states")
            points = reachable_targets(system, 2, seed=5)
            plan = c.request(make_request(points, execute=True))
            check_plan(system, plan, points)
            wait_for(lambda: len(trajs) == 1, what="trajectory on the bus")
            traj = trajs[0]
            np.testing.assert_allclose(traj.q[0], q_now, atol=1e-9)
            np.testing.assert_allclose(traj.q[-1], plan["solutions"][1]["q"]["arm0"], atol=1e-9)
            assert traj.t[-1] == pytest.approx(plan["trajectory"]["t"][-1])
            wait_for(lambda: driver.n_accepted == 1, what="driver accepted")
            wait_for(
                lambda: (
                    sim.measured().mode == "idle"
                    and np.allclose(sim.measured().q, traj.q[-1], atol=1e-6)
                ),
                timeout=traj.t[-1] + 10,
                what="arm at the last target",
            )
            sub.undeclare()
    finally:
        driver.stop()
        session.close()
