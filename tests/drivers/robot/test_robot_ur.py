"""Contract tests of the ur_rtde backend against a simulated controller: one command
register write per period, speed scaling, servo options, shutdown."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from drivers.robot.follower import STOP_JERK, Reference, TrajectoryFollower
from drivers.robot.node import RobotNode
from drivers.robot.ur import ARRIVE_TOLERANCE, URRobot
from drivers.robot.ur_fake import CMD_NONE, CMD_SERVO_STOP, CMD_SERVOJ, FakeURController
from planner.bus.session import Keys, open_session
from planner.errors import InputError
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests.drivers.conftest import Heartbeats, raw_session, wait_for
from tests.drivers.robot.test_robot_node import smooth_move

HOME = np.array(DEFAULT_HOME)
LIMITS = Limits.ur_default()


def make_robot(
    speed: float = 1.0, lag: bool = False, **kw: Any
) -> tuple[URRobot, FakeURController]:
    fake = FakeURController(HOME, speed_scaling=speed, lag=lag)
    robot = URRobot("fake", JOINT_NAMES_UR, LIMITS, control=fake, receive=fake, **kw)
    period(robot)  # the first period arms the RTDE watchdog (helper thread)
    while robot.call.busy:
        robot.call.poll()
    fake.cycles.clear()
    return robot, fake


def reference(dq: np.ndarray, duration: float) -> Reference:
    m = smooth_move(HOME, dq, duration)
    return Reference(*(np.asarray(a, dtype=float) for a in (m.t, m.q, m.qd, m.qdd)))


def period(robot: URRobot) -> None:
    robot.begin_period()
    robot.step()
    robot.end_period()


def run_until_rest(robot: URRobot, fake: FakeURController, limit: int = 20000) -> int:
    """Periods until the servo session ended (servoStop done) and the arm is idle."""
    for n in range(limit):
        period(robot)
        if not robot.servoing and not robot.call.busy and robot.measured().mode == "idle":
            return n + 1
    raise AssertionError(f"not at rest after {limit} periods")


def test_one_command_register_write_per_period() -> None:
    """Each controller cycle sees exactly one write of the command register: the servo
    target while moving (never overwritten by a watchdog kick), a kick at rest."""
    robot, fake = make_robot(lookahead_time=0.05, gain=500.0, watchdog_hz=25.0)
    assert fake.calls[0] == "setWatchdog" and fake.watchdog_hz == 25.0  # armed
    dq = np.array([0.1, 0, 0, 0, 0, -0.1])
    robot.command(reference(dq, 0.6))
    n = 400  # 0.8 s at 500 Hz: the move (0.6 s) and then rest
    for _ in range(n):
        period(robot)
    cycles = fake.cycles
    assert len(cycles) == n
    assert all(len(writes) <= 1 for writes, _ in cycles)  # never two writes in a cycle
    # a cycle without a write only while servoStop (helper thread) waits for the controller
    assert sum(len(w) == 0 for w, _ in cycles) <= 2
    reads = fake.servo_reads()
    servo = [k for k, r in enumerate(reads) if r == CMD_SERVOJ]
    assert 300 <= len(servo) <= 303  # the 0.6 s move: one servo target per period
    assert servo == list(range(servo[0], servo[-1] + 1))  # contiguous: none lost to a kick
    assert reads.count(CMD_SERVO_STOP) == 1 and reads[servo[-1] + 1] == CMD_SERVO_STOP
    assert set(reads[servo[-1] + 2 :]) == {CMD_NONE}  # at rest: the watchdog kick only
    np.testing.assert_allclose(fake.q, HOME + dq, atol=1e-9)
    assert fake.watchdog_trips == 0 and fake.running


def test_servo_targets_follow_the_reference() -> None:
    robot, fake = make_robot(lookahead_time=0.05, gain=500.0)
    dq = np.array([0.1, 0, 0, 0, 0, -0.1])
    targets: list[np.ndarray] = []
    servo_j = fake.servoJ

    def record(q: list[float], v: float, a: float, t: float, la: float, g: float) -> bool:
        assert (t, la, g) == (0.002, 0.05, 500.0)  # period 1/500 s, options forwarded
        targets.append(np.array(q))
        return servo_j(q, v, a, t, la, g)

    fake.servoJ = record  # type: ignore[method-assign]
    robot.command(reference(dq, 0.6))
    run_until_rest(robot, fake)
    # the commanded path is the reference sampled at 500 Hz (the midpoint at 0.3 s)
    np.testing.assert_allclose(targets[150], HOME + dq / 2, atol=2e-3)


def naive_shortfall(speed: float, dq: np.ndarray, duration: float) -> float:
    """The old loop against the same controller model: no time scaling, servoStop as soon
    as the command is at rest. Largest joint error at the end (rad)."""
    fake = FakeURController(HOME, speed_scaling=speed, lag=True)
    f = TrajectoryFollower(HOME, LIMITS, 0.002)
    f.follow(reference(dq, duration))
    while True:
        cmd = f.step()
        if cmd.mode not in ("approach", "following", "settle"):
            fake.servoStop()
            fake.cycle()
            return float(np.max(np.abs(fake.q - (HOME + dq))))
        fake.servoJ(cmd.q.tolist(), 0, 0, 0.002, 0.1, 300)
        fake.cycle()


@pytest.mark.parametrize("speed", [1.0, 0.5, 0.1])
def test_speed_slider_time_scales_and_arrives(speed: float) -> None:
    """The controller executes servo targets ``speed`` times slower: playback is time-scaled
    and the final target is held until the arm is there (no servoStop while it lags)."""
    dq = np.array([0.1, 0, 0, 0, 0, 0])
    before = naive_shortfall(speed, dq, 0.5)
    robot, fake = make_robot(speed=speed, lag=True)
    robot.command(reference(dq, 0.5))
    n = run_until_rest(robot, fake)
    err = np.max(np.abs(fake.q - (HOME + dq)))
    assert err <= ARRIVE_TOLERANCE
    reads = fake.servo_reads()
    n_servo = reads.count(CMD_SERVOJ)
    # time-scaled: the 0.5 s reference is played in 0.5 / speed s (+ approach, settle, hold)
    assert n_servo >= 0.5 / speed / 0.002
    assert n == len(reads) and reads.count(CMD_SERVO_STOP) == 1
    print(f"speed {speed:.0%}: end error {1e3 * err:.3f} mrad (old loop {1e3 * before:.1f} mrad)")
    if speed < 1.0:
        assert before > 10 * ARRIVE_TOLERANCE  # the model reproduces the old shortfall


def test_speed_below_floor_refuses_trajectories() -> None:
    robot, fake = make_robot(speed=0.02)
    period(robot)
    with pytest.raises(InputError, match=r"speed slider at 2 % \(< 5 %\): raise it"):
        robot.command(reference(np.full(6, 0.1), 0.5))
    fake.speed_scaling = 0.3
    period(robot)
    robot.command(reference(np.full(6, 0.1), 0.5))  # accepted now


def test_close_stops_servo_and_disconnects() -> None:
    robot, fake = make_robot()
    robot.command(reference(np.full(6, 0.1), 0.5))
    for _ in range(30):
        period(robot)
    robot.close()
    assert fake.calls[-3:] == ["servoStop", "disconnect", "disconnect"]


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
    fake.realtime = True  # waitPeriod paces the loop at 500 Hz
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
        assert "servoJ" not in fake.calls
        dq = np.array([0.3, 0, 0, 0, 0, 0])
        move = smooth_move(HOME, dq, 2.0, id="move", session="P")
        client.put(keys.trajectory("arm0"), move.model_dump_json())
        wait_for(lambda: np.abs(fake.qd[0]) > 0.1, what="motion")
        beats.stop()
        wait_for(lambda: "servoStop" in fake.calls, what="servoStop")
        servo = np.array(fake.targets)
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
