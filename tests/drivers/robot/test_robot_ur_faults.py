"""UR backend faults against the simulated controller: protective / emergency / safeguard
stops that need the operator's recover, reduced mode, a stale or hung RTDE link."""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
import pytest

from drivers.robot.node import RobotNode
from drivers.robot.ur import STALE_AFTER, URRobot
from drivers.robot.ur_fake import CMD_SERVOJ, FakeURController
from drivers.robot.ur_link import AsyncCall, RateLimitedLog, recover_body, recover_key
from planner.bus.session import Keys, decode, open_session
from planner.errors import InputError
from schemas.messages import RobotStatus
from tests.drivers.conftest import raw_session, wait_for
from tests.drivers.robot.test_robot_ur import HOME, LIMITS, make_robot, period, reference

STOPS = {"protective": "protective stop", "emergency": "robot emergency stop",
         "safeguard": "safeguard stop"}  # fmt: skip


@pytest.mark.parametrize("kind", list(STOPS))
def test_stop_latches_until_operator_recovers(kind: str) -> None:
    robot, fake = make_robot()
    robot.robot = "arm0"
    robot.command(reference(np.full(6, 0.1), 0.5))
    for _ in range(50):
        period(robot)
    getattr(fake, f"{kind}_stop")()
    n_servo = len(fake.targets)
    for _ in range(20):
        period(robot)
    assert len(fake.targets) == n_servo  # no servo target after the stop
    m = robot.measured()
    assert m.mode == "fault" and m.fault is not None and m.fault.startswith(STOPS[kind])
    assert m.safety == STOPS[kind] and m.protective_stop == (kind == "protective")
    assert "recover refused: " + STOPS[kind] in robot.recover()  # cause still there
    fake.release()  # the operator releases it on the pendant: the script stays stopped
    for _ in range(20):
        period(robot)
    m = robot.measured()
    assert m.mode == "fault" and "run `beamrelay robot recover --name arm0`" in str(m.fault)
    with pytest.raises(InputError, match="arm in fault"):
        robot.command(reference(np.zeros(6), 0.5))
    assert fake.reuploads == 0  # nothing re-arms the arm by itself
    assert robot.recover() == "recovering"
    for _ in range(5):
        period(robot)
    m = robot.measured()
    assert m.mode == "idle" and m.fault == "recovered by the operator"
    assert fake.reuploads == 1 and fake.running and fake.watchdog_hz == 10.0
    np.testing.assert_allclose(robot.follower.q, fake.q)  # re-synchronised to the arm
    robot.command(reference(fake.q - HOME, 0.3))  # moves again (from where it stopped)
    for _ in range(10):
        period(robot)
    assert fake.servo_reads()[-1] == CMD_SERVOJ


def test_recover_fails_without_remote_control() -> None:
    robot, fake = make_robot()
    fake.protective_stop()
    period(robot)
    fake.release()
    fake.remote_control = False
    period(robot)
    assert robot.recover() == "recovering"
    for _ in range(5):
        period(robot)
    m = robot.measured()
    assert m.mode == "fault" and "recover failed: returned False" in str(m.fault)


def test_reduced_mode_is_reported_not_a_fault() -> None:
    robot, fake = make_robot()
    fake.safety_mode = 2
    period(robot)
    m = robot.measured()
    assert m.mode == "idle" and m.safety == "reduced" and m.fault is None
    robot.command(reference(np.full(6, 0.05), 0.3))


def test_watchdog_trip_needs_recover() -> None:
    """A script stopped by the RTDE watchdog (the loop stalled) is a fault too."""
    robot, fake = make_robot(watchdog_hz=10.0)
    period(robot)
    for _ in range(49):  # the loop stalls: 98 ms of controller cycles without a write
        fake.cycle()
    assert fake.watchdog_trips == 0
    for _ in range(2):  # 102 ms > 1 / 10 Hz
        fake.cycle()
    assert fake.watchdog_trips == 1
    period(robot)
    assert robot.measured().mode == "fault"
    assert "control script not running" in str(robot.measured().fault)
    robot.recover()
    for _ in range(3):
        period(robot)
    assert robot.measured().mode == "idle" and fake.running


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; -rR lists a rerun
def test_stale_link_detected_fast_and_never_blocks() -> None:
    """The link dies mid-move: states freeze, and servoStop / disconnect would block for the
    fake's 300 s. The loop keeps its rate, the fault shows within ~STALE_AFTER, close()
    returns within the call timeouts."""
    robot, fake = make_robot()
    fake.realtime = True
    robot.command(reference(np.full(6, 0.2), 1.0))
    for _ in range(100):
        period(robot)
    fake.set_link(False)
    t0 = time.monotonic()
    worst = 0.0
    while robot.measured().mode != "fault":
        s = time.monotonic()
        period(robot)
        worst = max(worst, time.monotonic() - s)
        assert time.monotonic() - t0 < 1.0, "staleness not detected"
    detected = time.monotonic() - t0
    assert STALE_AFTER <= detected < STALE_AFTER + 0.15
    m = robot.measured()
    assert m.stale and m.fault is not None and m.fault.startswith("RTDE link stale")
    n_servo = len(fake.targets)
    for _ in range(50):
        s = time.monotonic()
        period(robot)
        worst = max(worst, time.monotonic() - s)
    assert len(fake.targets) == n_servo and worst < 0.05  # nothing sent, nothing blocked
    assert "servoStop" not in fake.calls  # never on a dead link: the RTDE watchdog stops
    t0 = time.monotonic()
    robot.close()
    assert time.monotonic() - t0 < 3.5  # disconnect x2 abandoned after their timeouts
    print(f"stale link detected after {1e3 * detected:.0f} ms; worst period {1e3 * worst:.1f} ms")


def test_async_call_times_out_and_recovers_when_the_call_returns() -> None:
    import threading

    gate = threading.Event()
    call = AsyncCall()
    assert call.start("servoStop", gate.wait, 0.05)
    assert not call.start("other", lambda: True, 1.0)  # one at a time
    time.sleep(0.08)
    assert call.poll() == ("servoStop", False, "no answer from the controller (call abandoned)")
    assert call.stuck and not call.start("other", lambda: True, 1.0)
    gate.set()
    time.sleep(0.02)
    assert call.poll() is None and not call.stuck


def test_rate_limited_log(capsys: pytest.CaptureFixture[str]) -> None:
    log = RateLimitedLog("arm0", every=0.2)
    for _ in range(100):
        log("fault: protective stop")
    log("fault: other")
    time.sleep(0.25)
    log("fault: protective stop")
    lines = capsys.readouterr().err.splitlines()
    assert lines == [
        "arm0: fault: protective stop",
        "arm0: fault: other",
        "arm0: fault: protective stop (repeated 99 times)",
    ]


def test_node_stale_link_and_recover_over_the_bus(hub: Any, endpoint: str, keys: Keys) -> None:
    """Through the node: a stale link stops the joint_states, says so in the status; a raw
    client's garbage on the recover key is ignored; a real recover request re-arms."""
    robot, fake = make_robot()
    robot.robot = "arm0"
    fake.realtime = True
    client = raw_session(endpoint)
    got: dict[str, list[float]] = {"states": []}
    statuses: list[RobotStatus] = []
    subs = [
        client.declare_subscriber(
            keys.joint_states("arm0"), lambda s: got["states"].append(time.monotonic())
        ),
        client.declare_subscriber(
            keys.status("arm0"),
            lambda s: statuses.append(decode(s.payload.to_bytes(), RobotStatus)),
        ),
    ]
    session = open_session(listen=False, endpoint=endpoint)
    node = RobotNode(session, keys, "arm0", robot, LIMITS, require_planner=False).start()
    try:
        wait_for(lambda: len(got["states"]) > 50, what="joint states")
        fake.set_link(False)
        t_dead = time.monotonic()
        wait_for(lambda: statuses and statuses[-1].mode == "fault", what="fault status")
        assert str(statuses[-1].fault).startswith("RTDE link stale")
        time.sleep(0.3)
        last = max(got["states"])
        assert last - t_dead < STALE_AFTER + 0.1  # no joint_states published as fresh
        fake.set_link(True)
        wait_for(lambda: "cause cleared" in str(statuses[-1].fault), what="cleared")
        key = recover_key(keys.prefix, "arm0")
        for junk in (b"", b"\xff\xfe", b"{}", json.dumps({"schema": "beamrelay.recover/1",
                     "robot": "arm1", "t": 0}).encode(), b"x" * 100_000):  # fmt: skip
            client.put(key, junk)
        time.sleep(0.3)
        assert fake.reuploads == 0 and statuses[-1].mode == "fault"
        client.put(key, recover_body("arm0", "test"))
        wait_for(lambda: statuses[-1].mode == "idle", what="recovered")
        assert fake.reuploads == 1 and statuses[-1].safety_mode == "normal"
        n = len(got["states"])
        wait_for(lambda: len(got["states"]) > n + 20, what="joint states again")
    finally:
        t0 = time.monotonic()
        node.stop()
        assert time.monotonic() - t0 < 5.0
        session.close()
        for s in subs:
            s.undeclare()
        client.close()


def test_watchdog_armed_in_the_first_period_and_refusal_is_a_fault() -> None:
    """Armed when the loop runs (a slow node start must not trip it); refused -> fault."""
    fake = FakeURController(HOME)
    robot = URRobot("fake", tuple(f"j{i}" for i in range(6)), LIMITS, control=fake, receive=fake)
    time.sleep(0.2)  # the node starting its parse worker, say: longer than 1/10 Hz
    assert fake.watchdog_hz == 0.0 and "setWatchdog" not in fake.calls
    for _ in range(5):
        period(robot)
    assert fake.watchdog_hz == 10.0 and fake.watchdog_trips == 0
    assert robot.measured().mode == "idle"  # no stale-link fault from the slow start
    bad = FakeURController(HOME)
    robot = URRobot("fake", tuple(f"j{i}" for i in range(6)), LIMITS, control=bad, receive=bad)
    bad.running = False
    for _ in range(5):
        period(robot)
    assert robot.measured().mode == "fault"


@pytest.mark.parametrize(
    ("payload", "words"),
    [
        (b"not json", "not a beamrelay.recover/1 body"),
        (b'{"schema": "beamrelay.stop/1", "robot": "arm0", "t": 1}', "not a beamrelay.recover/1"),
        (b'{"schema": "beamrelay.recover/1", "robot": "arm0", "t": "NaN"}', "not a beamrelay"),
        (b'{"schema": "beamrelay.recover/1", "robot": "arm0", "t": 1, "operator": 5}', "not a"),
        (b'{"schema": "beamrelay.recover/1", "robot": "arm1", "t": 1}', "for 'arm1', this is"),
        (b'{"schema": "beamrelay.recover/1", "robot": "arm0", "t": 1, "x": 1}', "not a"),
        (b"{" + b" " * 5000 + b"}", "bytes >"),
    ],
)
def test_a_recover_body_is_the_schema_model_or_refused(payload: bytes, words: str) -> None:
    from schemas.messages import parse_recover

    with pytest.raises(ValueError, match=words):
        parse_recover(payload, "arm0")


def test_a_recover_body_round_trips_with_the_operator_cut_to_its_limit() -> None:
    from schemas.messages import parse_recover

    assert parse_recover(recover_body("arm0", "ops"), "arm0") == "ops"
    assert parse_recover(recover_body("arm0", "x" * 500), "arm0") == "x" * 200
