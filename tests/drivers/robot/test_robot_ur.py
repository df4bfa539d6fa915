"""Contract tests of the ur_rtde backend against a fake arm that records every call."""

from __future__ import annotations

import datetime
from typing import Any

import numpy as np
import pytest

from drivers.robot.follower import STOP_JERK, Reference
from drivers.robot.node import RobotNode
from drivers.robot.ur import URRobot
from planner.errors import InputError
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from planner.service.bus import Keys, open_session
from tests.drivers.conftest import Heartbeats, raw_session, wait_for
from tests.drivers.robot.test_robot_node import smooth_move

HOME = np.array(DEFAULT_HOME)
LIMITS = Limits.ur_default()


class FakeUR:
    """Both RTDE interfaces in one: a perfect servo (actual q = last servoJ target)."""

    def __init__(self, q0: np.ndarray) -> None:
        self.q = np.array(q0, dtype=float)
        self.qd = np.zeros(6)
        self.calls: list[tuple[str, tuple[Any, ...]]] = []
        self.protective = False
        self.connected = True
        self.running = True

    def _rec(self, name: str, *args: Any) -> None:
        self.calls.append((name, args))

    def names(self) -> list[str]:
        return [c[0] for c in self.calls]

    # control interface
    def setWatchdog(self, min_frequency: float) -> bool:
        self._rec("setWatchdog", min_frequency)
        return True

    def kickWatchdog(self) -> bool:
        self._rec("kickWatchdog")
        return True

    def initPeriod(self) -> datetime.timedelta:
        self._rec("initPeriod")
        return datetime.timedelta(0)

    def waitPeriod(self, t0: datetime.timedelta) -> None:
        self._rec("waitPeriod", t0)

    def servoJ(
        self, q: list[float], v: float, a: float, t: float, lookahead: float, gain: float
    ) -> bool:
        self._rec("servoJ", list(q), v, a, t, lookahead, gain)
        q_new = np.array(q)
        self.qd = (q_new - self.q) / t
        self.q = q_new
        return True

    def servoStop(self, a: float = 10.0) -> bool:
        self._rec("servoStop")
        self.qd = np.zeros(6)
        return True

    def isConnected(self) -> bool:
        return self.connected

    def isProgramRunning(self) -> bool:
        return self.running

    def disconnect(self) -> None:
        self._rec("disconnect")

    # receive interface
    def getActualQ(self) -> list[float]:
        return self.q.tolist()

    def getActualQd(self) -> list[float]:
        return self.qd.tolist()

    def isProtectiveStopped(self) -> bool:
        return self.protective

    def isEmergencyStopped(self) -> bool:
        return False


def make_robot(**kw: Any) -> tuple[URRobot, FakeUR]:
    fake = FakeUR(HOME)
    return URRobot("fake", JOINT_NAMES_UR, LIMITS, control=fake, receive=fake, **kw), fake


def reference(dq: np.ndarray, duration: float) -> Reference:
    m = smooth_move(HOME, dq, duration)
    return Reference(*(np.asarray(a, dtype=float) for a in (m.t, m.q, m.qd, m.qdd)))


def period(robot: URRobot) -> None:
    robot.begin_period()
    robot.step()
    robot.end_period()


def test_one_servoj_per_period_with_options_and_watchdog() -> None:
    robot, fake = make_robot(lookahead_time=0.05, gain=500.0, watchdog_hz=25.0)
    assert fake.calls[0] == ("setWatchdog", (25.0,))
    dq = np.array([0.1, 0, 0, 0, 0, -0.1])
    robot.command(reference(dq, 0.6))
    n = 400  # 0.8 s at 500 Hz: the move (0.6 s) and then rest
    for _ in range(n):
        period(robot)
    names = fake.names()
    assert (
        names.count("initPeriod") == names.count("waitPeriod") == names.count("kickWatchdog") == n
    )
    servo = [c[1] for c in fake.calls if c[0] == "servoJ"]
    assert all(c[3:] == (0.002, 0.05, 500.0) for c in servo)  # period 1/500 s, options forwarded
    assert 300 <= len(servo) <= 303  # one per period while moving (0.6 s), none at rest
    # every period is: initPeriod, (servoJ|servoStop)?, kickWatchdog, waitPeriod
    per = " ".join(n for n in names[1:] if n in ("initPeriod", "servoJ", "servoStop", "waitPeriod"))
    assert per.count("servoJ servoJ") == 0 and names.count("servoStop") == 1
    np.testing.assert_allclose(fake.q, HOME + dq, atol=1e-9)
    # the commanded path is the reference sampled at 500 Hz (the midpoint at 0.3 s)
    mid = np.array(servo[150][0])
    np.testing.assert_allclose(mid, HOME + dq / 2, atol=2e-3)


def test_protective_stop_stops_servo_and_refuses_until_cleared() -> None:
    robot, fake = make_robot()
    robot.command(reference(np.full(6, 0.1), 0.5))
    for _ in range(50):
        period(robot)
    assert fake.names().count("servoStop") == 0
    fake.protective = True
    period(robot)
    assert fake.calls[-3][0] == "servoStop"  # servoStop, kickWatchdog, waitPeriod
    n_servo = fake.names().count("servoJ")
    for _ in range(20):
        period(robot)
    assert fake.names().count("servoJ") == n_servo and fake.names().count("servoStop") == 1
    m = robot.measured()
    assert m.mode == "fault" and m.protective_stop and m.fault == "protective stop"
    with pytest.raises(InputError, match="protective stop"):
        robot.command(reference(np.full(6, 0.1), 0.5))
    fake.protective = False
    period(robot)
    assert robot.measured().mode == "idle" and robot.measured().fault is None
    np.testing.assert_allclose(robot.follower.q, fake.q)  # re-synchronised to the arm


@pytest.mark.parametrize("what", ["connected", "running"])
def test_lost_connection_or_script_stops(what: str) -> None:
    robot, fake = make_robot()
    robot.command(reference(np.full(6, 0.1), 0.5))
    for _ in range(30):
        period(robot)
    setattr(fake, what, False)
    period(robot)
    assert fake.names().count("servoStop") == 1 and robot.measured().mode == "fault"


def test_close_stops_servo_and_disconnects() -> None:
    robot, fake = make_robot()
    robot.command(reference(np.full(6, 0.1), 0.5))
    for _ in range(30):
        period(robot)
    robot.close()
    assert fake.names()[-3:] == ["servoStop", "disconnect", "disconnect"]


def test_bad_servo_options_are_input_errors() -> None:
    with pytest.raises(InputError) as exc:
        make_robot(lookahead_time=0.5)
    assert exc.value.where == "--lookahead"
    with pytest.raises(InputError):
        make_robot(gain=50.0)


def test_stale_planner_brakes_then_servo_stop(hub: Any, endpoint: str, keys: Keys) -> None:
    """Through the node: the planner's heartbeat stops mid-move (its token stays) ->
    decelerate, servoStop; a position jump is refused before any servoJ sees it."""
    robot, fake = make_robot()
    robot.control.waitPeriod = _sleeping_wait  # type: ignore[method-assign]
    client = raw_session(endpoint)
    token = client.liveliness().declare_token(keys.alive("planner"))
    beats = Heartbeats(client, keys.prefix, "P")
    session = open_session(listen=False, endpoint=endpoint)
    statuses: list[Any] = []
    sub = client.declare_subscriber(keys.status("arm0"), statuses.append)
    node = RobotNode(session, keys, "arm0", robot, LIMITS).start()
    try:
        wait_for(lambda: node.planner_alive and "P" in node.heartbeats, what="planner")
        jump = smooth_move(HOME, np.zeros(6), 0.1, id="jump", session="P")
        q = np.asarray(jump.q)
        q[20:, 0] += 0.3  # shoulder_pan: 0.3 rad in 2 ms
        client.put(
            keys.trajectory("arm0"), jump.model_copy(update={"q": q.tolist()}).model_dump_json()
        )
        wait_for(lambda: node.n_rejected == 1, what="rejection")
        assert node.ack is not None and node.ack.id == "jump"
        assert (
            node.ack.reason
            == "q[20]: shoulder_pan moves 0.3000 rad in 0.0020 s = 150.0 rad/s > 3.1416 rad/s"
        )
        assert "servoJ" not in fake.names()
        dq = np.array([0.3, 0, 0, 0, 0, 0])
        move = smooth_move(HOME, dq, 2.0, id="move", session="P")
        client.put(keys.trajectory("arm0"), move.model_dump_json())
        wait_for(lambda: np.abs(fake.qd[0]) > 0.1, what="motion")
        beats.stop()
        wait_for(lambda: "servoStop" in fake.names(), what="servoStop")
        servo = np.array([c[1][0] for c in fake.calls if c[0] == "servoJ"])
        v = np.abs(np.diff(servo[:, 0])) / 0.002
        k = int(np.argmax(v))  # peak speed when the brake began (mid-move)
        assert np.all(np.diff(v[k:]) <= 1e-9)  # monotone deceleration to the servoStop
        # the last servoJ step ends 1-2 periods before rest, on the final jerk ramp
        # (v = j tau^2 / 2): its mean speed is at most j / 6 (3 r^2 - 3 r dt + dt^2) at r = 2 dt
        assert v[-1] <= 7 / 6 * STOP_JERK * 0.002**2
        assert fake.q[0] < HOME[0] + 0.3 - 1e-3  # stopped short of the target
        assert node.stopped_by is not None and "heartbeat lost: session P" in node.stopped_by
    finally:
        node.stop()
        session.close()
        sub.undeclare()
        token.undeclare()
        client.close()


def _sleeping_wait(t0: Any) -> None:
    import time

    time.sleep(0.002)
