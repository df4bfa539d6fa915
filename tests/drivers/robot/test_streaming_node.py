"""Setpoint streams through the robot node, on a simulated clock: the node's own control
period (:meth:`RobotNode.period`) with the simulated arm, fed by an in-process bus. Every
time here is simulated (no sleeping, no wall-clock asserts)."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from drivers.robot.follower import STOP_ACCELERATION, STOP_JERK, Reference
from drivers.robot.intake import Verdict
from drivers.robot.node import HEARTBEAT_TIMEOUT, LATE_SETPOINT, RobotNode
from drivers.robot.setpoint_check import STALE_AFTER
from drivers.robot.sim import SimRobot
from planner.bus.session import Keys
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests.drivers.robot.fake_bus import FakeBus, SimClock

HOME = np.array(DEFAULT_HOME)
LIMITS = Limits.ur_default()
KEYS = Keys("sim")
DT = 0.002
SENDER_OFFSET = 1.7e9  # the sender's clock differs from the driver's monotonic one
E3 = np.eye(6)[3]


def wave(t: float, amp: float = 0.1, freq: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """wrist_1 on ``amp (1 - cos w t)^2 / 4``: starts at rest with zero acceleration (a
    reference the jerk limit can follow from rest); peaks 0.31 rad/s, 2 rad/s^2, 34 rad/s^3."""
    w = 2 * math.pi * freq
    c, s = math.cos(w * t), math.sin(w * t)
    return HOME + amp * (1 - c) ** 2 / 4 * E3, amp * (1 - c) * w * s / 2 * E3


class Rig:
    """A robot node (simulated arm, laser gate on output 0) and a sender on a fake bus."""

    def __init__(self, *, gate: bool = True, planner: bool = True) -> None:
        self.bus, self.clock = FakeBus(), SimClock()
        self.sim = SimRobot(JOINT_NAMES_UR, HOME, LIMITS, realtime=False)
        self.node = RobotNode(self.bus, KEYS, "arm0", self.sim, LIMITS, clock=self.clock,
                              gate_output=0 if gate else None).attach()  # fmt: skip
        if planner:
            self.bus.token(KEYS.alive("planner"))
        self.beating, self.k, self.seq = True, 0, 0
        self.q: list[np.ndarray] = []
        self.qdd: list[np.ndarray] = []
        self.gate: list[bool] = []
        self.modes: list[str] = []

    def send(self, q: np.ndarray, qd: np.ndarray, laser: bool = False, **kw: Any) -> None:
        msg = {"robot": "arm0", "t": self.clock.t + SENDER_OFFSET, "session": "S",
               "seq": self.seq, "id": "r", "q": q.tolist(), "qd": qd.tolist(), "laser_on": laser}  # fmt: skip
        msg.update(kw)
        self.seq += 1
        self.bus.put(KEYS.setpoint("arm0"), json.dumps(msg))

    def period(self, n: int = 1) -> None:
        for _ in range(n):
            if self.beating and self.k % 5 == 0:  # 100 Hz
                beat = {"schema": "beamrelay.heartbeat/1", "t": self.clock.t,
                        "session": "S", "seq": self.k}  # fmt: skip
                self.bus.put(KEYS.heartbeat, json.dumps(beat))
            self.node.period()
            self.clock.t += DT
            self.k += 1
            self.q.append(self.sim.follower.q.copy())
            self.qdd.append(self.sim.follower.qdd.copy())
            self.gate.append(bool(getattr(self.sim, "gate", False)))
            self.modes.append(self.sim.follower.mode)

    def stream(self, ref: Any, seconds: float, laser: Any = lambda t: False) -> float:
        """Send ``ref(t)`` once per period for ``seconds``; the stream time at the end."""
        t0 = self.clock.t
        for k in range(round(seconds / DT)):
            q, qd = ref(k * DT)
            self.send(q, qd, laser(k * DT))
            self.period()
        return self.clock.t - t0

    def ack(self) -> dict[str, Any]:
        stream: dict[str, Any] = self.bus.last(KEYS.status("arm0"))["stream"]
        return stream

    def status(self) -> dict[str, Any]:
        status: dict[str, Any] = self.bus.last(KEYS.status("arm0"))
        return status


def within_limits(rig: Rig, acc: float = 5.0, jerk: float = 50.0) -> None:
    """Velocity and acceleration of the arm's positions (finite differences), jerk of its
    commanded acceleration (positions carry the 0.24 us resolution of a UNIX ``t``:
    1e-7 rad, which a third difference at 2 ms turns into ~10 rad/s^3)."""
    v = np.diff(np.array(rig.q), axis=0) / DT
    a = np.diff(v, axis=0) / DT
    j = np.diff(np.array(rig.qdd), axis=0) / DT
    slack = 1 + 1e-6
    assert np.abs(v).max() <= math.pi * slack
    assert np.abs(a).max() <= acc * slack
    assert np.abs(j).max() <= jerk * slack


def test_a_stream_is_played_exactly_and_switches_the_laser() -> None:
    rig = Rig()
    rig.period(3)
    rig.stream(wave, 1.5, laser=lambda t: 0.5 <= t < 1.0)
    q = np.array(rig.q[3:])
    expected = np.array([wave(k * DT)[0] for k in range(len(q))])  # on setpoint k after period k
    err = np.abs(q - expected).max()
    print(f"largest deviation from the streamed wave: {err:.2e} rad")
    assert err < 1e-6
    within_limits(rig)
    assert set(rig.modes[3:]) == {"streaming"} and rig.status()["mode"] == "streaming"
    gate = np.array(rig.gate[3:])
    lit = np.flatnonzero(gate)
    assert lit[0] == round(0.5 / DT) and lit[-1] == round(1.0 / DT) - 1 and gate[lit].all()
    assert len(lit) == lit[-1] - lit[0] + 1
    ack = rig.ack()  # the last status published (10 Hz)
    assert ack["state"] == "streaming" and ack["id"] == "r" and ack["session"] == "S"
    now = rig.node.streams.status()
    assert now is not None and (now.n, now.seq) == (round(1.5 / DT), round(1.5 / DT) - 1)


def test_silence_mid_motion_stops_the_arm_within_50_ms_plus_braking() -> None:
    rig = Rig()
    rig.stream(wave, 0.25, laser=lambda t: t > 0.1)  # fast, laser on
    last = rig.clock.t - DT  # received time of the last setpoint
    n0 = len(rig.q)
    rig.period(100)  # nothing sent
    qd = np.diff(np.array(rig.q), axis=0) / DT
    rest = next(k for k in range(n0, len(rig.q)) if np.all(qd[k - 1] == 0)) * DT
    dark = next(k for k in range(n0, len(rig.q)) if not rig.gate[k]) * DT
    t_rest, t_dark = rest - (last - (rig.clock.t - len(rig.q) * DT)), 0.0
    t_dark = dark - (last - (rig.clock.t - len(rig.q) * DT))
    braking = rig.modes.index("braking")
    v0 = np.abs(qd[braking - 1]).max()
    brake = v0 / STOP_ACCELERATION + STOP_ACCELERATION / STOP_JERK
    print(f"silence to laser off {1e3 * t_dark:.0f} ms, to rest {1e3 * t_rest:.0f} ms "
          f"(50 ms + braking {1e3 * brake:.0f} ms from {v0:.2f} rad/s)")  # fmt: skip
    # treatment off at the first late setpoint (3 periods), long before the stream ends
    assert LATE_SETPOINT < t_dark <= LATE_SETPOINT + 2 * DT
    assert STALE_AFTER < t_rest <= STALE_AFTER + brake + 3 * DT
    assert v0 > 0.2 and rig.modes[-1] == "stopped"
    within_limits(rig, STOP_ACCELERATION, STOP_JERK)
    ack = rig.ack()
    assert ack["state"] == "ended" and ack["braked"] is True
    assert ack["reason"] == "setpoint stream stale: no setpoint for 52 ms"
    assert rig.status()["fault"] == ack["reason"] and rig.status()["laser_on"] is False


def test_silence_at_rest_on_the_last_setpoint_is_the_normal_end() -> None:
    rig = Rig()
    goal = HOME + 0.003 * E3
    for k in range(200):  # a small correction, then held until the arm rests on it
        rig.send(HOME + min(k, 3) * 0.001 * E3, np.zeros(6))
        rig.period()
    assert np.all(rig.sim.follower.q == goal) and np.all(rig.sim.follower.qd == 0)
    rig.period(30)
    assert rig.modes[-1] == "idle" and rig.status()["fault"] is None
    ack = rig.ack()
    assert (ack["state"], ack["braked"], ack["n"]) == ("ended", False, 200)
    np.testing.assert_array_equal(rig.sim.follower.q, goal)


def moving(rig: Rig) -> None:
    """Stream the wave for 0.2 s with the laser on: the arm moves at ~0.3 rad/s."""
    rig.stream(wave, 0.2, laser=lambda t: True)
    assert rig.sim.gate and np.abs(rig.sim.follower.qd).max() > 0.2


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (
            lambda q, qd: {"q": list(q + 0.02 * E3)},
            "q: wrist_1 moves 0.0204 rad in 0.0020 s since seq 99 = 10.2 rad/s > 3.1416 rad/s",
        ),
        (lambda q, qd: {"qd": list(qd + 0.1 * E3)}, "qd: wrist_1 velocity changes 0.1044 rad/s"),
        (
            lambda q, qd: {"q": list(q[:5]), "qd": list(qd[:5])},
            "q: expected 6 numbers (one per joint), got 5",
        ),
        (
            lambda q, qd: {"q": [*q[:3], 7.0, *q[4:]]},
            "q: 7.0000 rad on joint wrist_1 above upper limit 6.2832 rad",
        ),
        (lambda q, qd: {"robot": "arm1"}, "robot: setpoint is for robot 'arm1'"),
        (lambda q, qd: {"session": "T"}, "session: setpoint of stream session T id r while "),
        (lambda q, qd: {"seq": 3}, "seq: 3 does not follow 99 (seq must increase)"),
    ],
)
def test_a_bad_setpoint_ends_the_stream_and_brakes(change: Any, reason: str) -> None:
    rig = Rig()
    moving(rig)
    q, qd = wave(0.2)
    msg = {"robot": "arm0", "t": rig.clock.t + SENDER_OFFSET, "session": "S", "seq": rig.seq,
           "id": "r", "q": list(q), "qd": list(qd), "laser_on": True}  # fmt: skip
    msg.update(change(q, qd))
    rig.bus.put(KEYS.setpoint("arm0"), json.dumps(msg))
    rig.seq += 1
    rig.period()
    assert not rig.sim.gate and rig.modes[-1] == "braking"  # laser off in the same period
    ack = rig.ack()
    assert ack["state"] == "rejected" and ack["braked"] is True, ack
    assert ack["reason"].startswith(reason), ack["reason"]
    assert rig.status()["fault"] == f"setpoint rejected: {ack['reason']}"
    rig.stream(lambda t: wave(0.2 + t), 0.2, laser=lambda t: True)  # the sender goes on
    assert rig.modes[-1] == "stopped" and not any(rig.gate[-100:])
    assert rig.ack() == ack  # ignored, not a new stream
    rig.period(30)  # after a pause, a new stream from where the arm is starts
    here = rig.sim.follower.q.copy()
    rig.stream(lambda t: (here, np.zeros(6)), 0.01)
    assert rig.ack()["state"] == "streaming" and rig.modes[-1] == "streaming"


def test_nan_or_garbage_in_a_stream_ends_it() -> None:
    rig = Rig()
    moving(rig)
    rig.bus.put(KEYS.setpoint("arm0"), b'{"robot": "arm0", "q": [NaN]}')
    rig.period()
    assert rig.ack()["state"] == "rejected" and rig.modes[-1] == "braking"
    assert rig.ack()["reason"].startswith("q[0]: expected a finite number, got nan")


@pytest.mark.parametrize(
    ("setup", "first", "reason"),
    [
        (
            "",
            {"q": list(HOME + 0.05 * E3)},
            "q: stream starts 0.0500 rad from the current state on joint wrist_1 (tolerance 0.01 rad)",
        ),
        (
            "",
            {"qd": list(0.5 * E3)},
            "qd: stream starts 0.5000 rad/s from the current state on joint wrist_1",
        ),
        (
            "",
            {"session": "ghost"},
            "session: no heartbeat from planner session ghost within 100 ms (last: never)",
        ),
        (
            "no gate",
            {"laser_on": True},
            "laser_on: laser_on given, but this driver switches no laser gate",
        ),
        ("no planner", {}, "body: no planner alive (watchdog): not moving"),
        ("trajectory", {}, "body: a trajectory is executing (mode approach): stream once the"),
    ],
)
def test_a_stream_that_may_not_start_is_refused(setup: str, first: Any, reason: str) -> None:
    rig = Rig(gate=setup != "no gate", planner=setup != "no planner")
    rig.period(5)
    if setup == "trajectory":
        t = np.array([0.0, 1.0])
        ref = Reference(t, np.vstack([HOME, HOME]), np.zeros((2, 6)), np.zeros((2, 6)))
        rig.node._decide(Verdict(rig.clock.t, "T", "S", ref, None))
    q = np.array(first.pop("q", HOME))
    qd = np.array(first.pop("qd", np.zeros(6)))
    rig.send(q, qd, **first)
    rig.period()
    ack = rig.ack()
    assert ack["state"] == "rejected" and ack["reason"].startswith(reason), ack
    assert ack["n"] == 0 and rig.modes[-1] != "streaming"
    np.testing.assert_array_equal(rig.sim.follower.q, HOME)


def test_heartbeat_loss_ends_the_stream() -> None:
    rig = Rig()
    moving(rig)
    rig.beating = False
    last_beat = (rig.k - 1) // 5 * 5  # period index of the last heartbeat
    rig.stream(lambda t: wave(0.2 + t), 0.2, laser=lambda t: True)
    braking = rig.modes.index("braking")
    assert HEARTBEAT_TIMEOUT < (braking - last_beat) * DT <= HEARTBEAT_TIMEOUT + 2 * DT
    assert not rig.gate[braking] and rig.ack()["state"] == "ended"
    assert rig.ack()["reason"].startswith("planner heartbeat lost: session S silent for 10")


def test_a_stop_request_ends_the_stream_and_later_setpoints_do_not_restart_it() -> None:
    rig = Rig()
    moving(rig)
    rig.bus.put(KEYS.stop, b"\x00 any body")
    rig.stream(lambda t: wave(0.2 + t), 0.3, laser=lambda t: True)
    assert rig.ack()["state"] == "ended" and rig.ack()["reason"] == "stop requested on sim/stop"
    assert rig.modes[-1] == "stopped" and not any(rig.gate[-140:])


def test_a_trajectory_replaces_the_stream_through_the_approach() -> None:
    rig = Rig()
    moving(rig)
    f = rig.sim.follower
    t = np.arange(0.0, 0.5 + DT / 2, DT)
    q = f.q + np.outer(np.zeros_like(t), E3)
    ref = Reference(t, q, np.zeros_like(q), np.zeros_like(q))
    rig.node._decide(Verdict(rig.clock.t, "T", "S", ref, None))
    assert rig.node.ack is not None and rig.node.ack.accepted
    rig.stream(lambda t: wave(0.2 + t), 0.1, laser=lambda t: True)  # still sending: ignored
    assert rig.ack()["state"] == "ended" and rig.ack()["reason"] == "replaced by trajectory T"
    assert rig.ack()["braked"] is False and "approach" in rig.modes
    rig.period(600)
    assert rig.modes[-1] == "idle" and np.abs(f.q - q[-1]).max() == 0
    within_limits(rig)


def test_the_ur_backend_streams_through_servoj_one_write_per_cycle() -> None:
    """The UR backend on the simulated controller: each period's streamed target goes out
    as that cycle's one servoJ; the stream's silence ends the servo session with servoStop
    once the arm rests on the last setpoint."""
    from drivers.robot.ur import URRobot
    from drivers.robot.ur_fake import CMD_SERVOJ, FakeURController

    fake = FakeURController(HOME, lag=False)
    ur = URRobot("fake", JOINT_NAMES_UR, LIMITS, control=fake, receive=fake)
    rig = Rig()
    rig.sim = ur  # type: ignore[assignment]  # Rig records follower states only
    rig.node = RobotNode(rig.bus, KEYS, "arm0", ur, LIMITS, clock=rig.clock).attach()
    rig.bus.token(KEYS.alive("planner"))
    rig.period(5)
    while ur.call.busy:  # the first period armed the RTDE watchdog in a helper thread
        ur.call.poll()
    fake.cycles.clear()
    goal = HOME + 0.004 * E3
    for k in range(100):
        rig.send(HOME + min(k, 4) / 4 * (goal - HOME), np.zeros(6))
        rig.period()
    assert rig.status()["mode"] == "streaming"
    np.testing.assert_allclose(fake.targets[-1], goal, atol=0)
    assert all(writes == [CMD_SERVOJ] for writes, _ in fake.cycles)
    rig.period(40)
    while ur.call.busy:
        ur.call.poll()
    assert "servoStop" in fake.calls and not ur.servoing
    assert rig.ack()["state"] == "ended" and rig.ack()["braked"] is False
    np.testing.assert_allclose(fake.getActualQ(), goal, atol=1e-12)


def test_setpoints_queued_before_a_stop_do_not_start_a_stream_after_it() -> None:
    """Setpoints wait in Zenoh's queue while a stop arrives (its callback runs at once):
    the next period sees the stop and discards them; the arm at rest stays stopped, no
    stream starts, and a later stream (after its 50 ms pause) is judged afresh."""
    rig = Rig()
    rig.period(3)
    for k in range(3):
        q, qd = wave(k * DT)
        rig.send(q, qd)
    rig.bus.put(KEYS.stop, b"halt")
    rig.period(5)
    assert rig.node.streams.active is None and rig.node.streams.status() is None
    assert rig.node.stopped_by == "stop requested on sim/stop"
    assert "streaming" not in rig.modes
