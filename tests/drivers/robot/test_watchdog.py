"""The robot driver's heartbeat watchdog and laser gate on a simulated clock: trajectories
through :meth:`RobotNode.period` with the simulated arm on an in-process bus (the stream
cases are in test_streaming_node.py). Every time here is simulated, so the asserts are
exact: braking starts at the heartbeat timeout, the gate switches at the interval edges."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.robot.follower import Reference
from drivers.robot.intake import Verdict
from drivers.robot.node import HEARTBEAT_TIMEOUT, MAX_SESSIONS
from tests.drivers.robot.test_robot_node import smooth_move
from tests.drivers.robot.test_streaming_node import DT, HOME, KEYS, Rig

DQ = np.array([0.1, -0.05, 0.05, 0.1, -0.1, 0.2])
NS = 1e-9  # s: how close to an edge the clock is set


def reference(duration: float, laser_on: list[list[float]] | None = None) -> Reference:
    m = smooth_move(HOME, DQ, duration)
    lit = None if laser_on is None else np.asarray(laser_on, dtype=float)
    return Reference(np.asarray(m.t), np.asarray(m.q), np.asarray(m.qd), np.asarray(m.qdd), lit)


def beat(rig: Rig, session: str = "S") -> float:
    """One heartbeat of ``session`` received now and taken by the control loop at once (it
    takes the queued beats at the start of every period, this one included); the time it
    is heard (driver clock, s)."""
    body = {"schema": "beamrelay.heartbeat/1", "t": rig.clock(), "session": session,
            "seq": rig.k}  # fmt: skip
    rig.bus.put(KEYS.heartbeat, json.dumps(body))
    rig.node._take_heartbeats(rig.clock())
    return rig.clock()


def send(rig: Rig, ref: Reference, id: str, session: str | None = "S") -> dict[str, object]:
    """Decide on ``ref`` as the control loop does when its parse verdict arrives; the ack."""
    rig.node._decide(Verdict(rig.clock(), id, session, ref, None))
    assert rig.node.ack is not None and rig.node.ack.id == id
    return rig.node.ack.model_dump()


def period_at(rig: Rig, t: float) -> str:
    """One control period starting at driver time ``t``; the arm's mode after it."""
    rig.clock.t = t
    rig.node.period()
    return rig.sim.follower.mode


def test_braking_starts_exactly_at_the_heartbeat_timeout() -> None:
    rig = Rig()
    rig.period(5)
    assert send(rig, reference(2.0, [[0.0, 1.9]]), "A")["accepted"]
    rig.period(300)  # 0.6 s following with the laser on, beating at 100 Hz
    assert rig.sim.follower.mode == "following" and rig.sim.gate
    rig.beating = False
    t_beat = beat(rig)  # the last heartbeat
    for k in range(1, 50):  # periods up to the timeout: still following, laser on
        assert period_at(rig, t_beat + k * DT) == "following"
    assert period_at(rig, t_beat + HEARTBEAT_TIMEOUT - NS) == "following" and rig.sim.gate
    assert period_at(rig, t_beat + HEARTBEAT_TIMEOUT + NS) == "braking"
    assert not rig.sim.gate
    assert rig.node.stopped_by == "planner heartbeat lost: session S silent for 100 ms"
    gate = rig.node.gate
    assert gate is not None and gate.switches[-1].reason == rig.node.stopped_by
    # heartbeats of another session do not count
    rig2 = Rig()
    rig2.period(5)
    assert send(rig2, reference(2.0), "A")["accepted"]
    rig2.beating = False
    t_beat = beat(rig2)
    for k in range(1, 60):
        beat(rig2, "intruder")
        following = period_at(rig2, t_beat + k * DT) == "following"
        assert following == (k * DT < HEARTBEAT_TIMEOUT - NS), k
    assert rig2.node.stopped_by == "planner heartbeat lost: session S silent for 100 ms"


def test_the_gate_switches_at_the_interval_edges() -> None:
    rig = Rig()
    rig.period(5)
    assert send(rig, reference(0.8, [[0.2, 0.5], [0.6, 0.6]]), "lit")["accepted"]
    played = []  # (trajectory time played, gate) per period
    for _ in range(round(0.8 / DT) + 20):
        rig.period()
        played.append((rig.sim.follower.tau, rig.gate[-1]))
    lit = np.array([tau for tau, on in played if on])
    assert len(lit) == 151 + 1  # 0.2 s to 0.5 s inclusive, and the single period at 0.6 s
    assert lit[0] == pytest.approx(0.2, abs=NS) and lit[150] == pytest.approx(0.5, abs=NS)
    assert lit[151] == pytest.approx(0.6, abs=NS)
    gate = rig.node.gate
    assert gate is not None
    on, off, on2, off2 = gate.switches[-4:]
    assert (on.on, off.on, on2.on, off2.on) == (True, False, True, False)
    assert on.edge == pytest.approx(0.2) and on.lag == pytest.approx(0.0, abs=NS)
    assert off.edge == pytest.approx(0.5) and off.lag == pytest.approx(DT, abs=NS)
    assert on.latency == 0.0 and off.latency == 0.0  # the fake clock stands within a period
    assert rig.status()["laser_on"] is False and rig.modes[-1] == "idle"


def test_a_stop_request_forces_the_gate_off_in_the_next_period() -> None:
    rig = Rig()
    rig.period(5)
    assert send(rig, reference(3.0, [[0.1, 2.9]]), "long")["accepted"]
    rig.period(200)
    assert rig.sim.gate
    rig.bus.put(KEYS.stop, b"anything")
    rig.period()
    assert not rig.gate[-1] and rig.modes[-1] == "braking"
    gate = rig.node.gate
    assert gate is not None and gate.switches[-1].reason == "stop requested on sim/stop"
    rig.period(400)  # braking, then stopped: it stays off
    assert not any(rig.gate[-401:]) and rig.modes[-1] == "stopped"


def test_trajectories_need_a_fresh_heartbeat_of_their_session() -> None:
    rig = Rig(gate=False)
    rig.period(5)
    ref = reference(0.3)
    assert send(rig, ref, "none", None)["reason"] == (
        "session: no planner session given (a planner must send it)"
    )
    assert send(rig, ref, "ghost", "ghost")["reason"] == (
        "session: no heartbeat from planner session ghost within 100 ms (last: never)"
    )
    # heartbeats that do not parse, or name the session in the wrong field, do not count
    for body in (b"ghost", b'{"session":"ghost"}', b'{"schema":"beamrelay.heartbeat/1",'
                 b'"t":1,"session":"ghost","seq":-1}', b"\xff" * 5000):  # fmt: skip
        rig.bus.put(KEYS.heartbeat, body)
    rig.node._take_heartbeats(rig.clock())
    assert rig.node.n_bad_heartbeats == 4
    for n in range(200):  # a flood of made-up sessions: remembered ones stay bounded
        beat(rig, f"fake{n}")
    assert len(rig.node.heartbeats) == MAX_SESSIONS and "fake199" in rig.node.heartbeats
    assert "last: never" in str(send(rig, ref, "ghost2", "ghost")["reason"])
    rig.beating = False
    t_beat = beat(rig)
    rig.clock.t = t_beat + HEARTBEAT_TIMEOUT - NS
    assert send(rig, ref, "edge", "S")["accepted"]  # just within 100 ms: still fresh
    rig2 = Rig(gate=False)
    rig2.period(5)
    rig2.beating = False
    t_beat = beat(rig2)
    rig2.clock.t = t_beat + 0.2
    assert send(rig2, ref, "stale", "S")["reason"] == (
        "session: no heartbeat from planner session S within 100 ms (last: 200 ms ago)"
    )
    np.testing.assert_array_equal(rig2.sim.follower.q, HOME)  # nothing moved
    beat(rig2)
    assert send(rig2, ref, "fresh", "S")["accepted"]


def test_queue_one_trajectory_behind_the_running_one() -> None:
    """While A runs: C (starts at the arm's start, not A's end) is refused; B and then B2
    (both start at A's last sample) are queued, B2 replaces B and runs when A ends."""
    rig = Rig(gate=False)
    rig.period(5)

    def move(q0: np.ndarray, dq: np.ndarray, duration: float) -> Reference:
        m = smooth_move(q0, dq, duration)
        return Reference(np.asarray(m.t), np.asarray(m.q), np.asarray(m.qd), np.asarray(m.qdd))

    dq = np.array([0.2, 0, 0, 0, 0, 0.15])
    assert send(rig, move(HOME, dq, 1.5), "A")["accepted"]
    rig.period(10)
    assert rig.modes[-1] == "following"
    c = send(rig, move(HOME, dq, 1.0), "C")
    assert not c["accepted"] and c["reason"] == (
        "q[0]: starts 0.2000 rad from the running trajectory's last sample on joint "
        "shoulder_pan (tolerance 0.01 rad)"
    )
    end_a = HOME + dq
    assert send(rig, move(end_a + 0.005, np.full(6, 0.05), 0.5), "B")["accepted"]
    b2 = np.array([0, 0.1, -0.1, 0, 0, 0])
    assert send(rig, move(end_a, b2, 0.5), "B2")["accepted"]
    assert rig.sim.follower.mode == "following"  # A still runs
    rig.period(round(2.5 / DT))
    assert rig.modes[-1] == "idle" and rig.node.n_accepted == 3
    np.testing.assert_allclose(rig.sim.follower.q, end_a + b2, atol=1e-9)
    qs = np.array(rig.q)
    assert np.min(np.abs(qs - end_a).max(axis=1)) < 1e-9  # played A's last sample, then B2
    assert np.all(qs[:, 3] == HOME[3])  # B (which moves joint 3) never ran


def test_a_planner_that_hangs_while_the_loop_stalls_is_silent_from_its_last_beat() -> None:
    """The control loop stalls 300 ms (no period runs) while the planner beats for 100 ms
    and then hangs: its queued beats count at most HEARTBEAT_TIMEOUT past their sending
    (0.09 + 0.1 s), so the first period after the stall brakes (silent 110 ms), not one
    100 ms later."""
    rig = Rig()
    rig.period(5)
    assert send(rig, reference(2.0, [[0.0, 1.9]]), "A")["accepted"]
    rig.period(100)
    rig.beating = False
    t0 = rig.clock()
    for k in range(10):  # queued, not taken: no period runs meanwhile
        rig.clock.t = t0 + 0.01 * k
        body = {"schema": "beamrelay.heartbeat/1", "t": rig.clock(),
                "session": "S", "seq": 1000 + k}  # fmt: skip
        rig.bus.put(KEYS.heartbeat, json.dumps(body))
    last = t0 + 0.09
    assert period_at(rig, t0 + 0.3) == "braking" and not rig.sim.gate
    assert rig.node.heartbeats["S"] == pytest.approx(last + HEARTBEAT_TIMEOUT, abs=1e-9)
    assert rig.node.stopped_by == "planner heartbeat lost: session S silent for 110 ms"


def test_a_beat_stamped_in_the_future_cannot_keep_a_session_alive() -> None:
    """A beat whose ``t`` lies an hour ahead lowers the session's offset: it counts as heard
    when it was taken, and the session's later honest beats look older, never fresher."""
    rig = Rig()
    rig.period(5)
    assert send(rig, reference(2.0), "A")["accepted"]
    rig.beating = False
    body = {"schema": "beamrelay.heartbeat/1", "t": rig.clock() + 3600.0,
            "session": "S", "seq": 99999}  # fmt: skip
    rig.bus.put(KEYS.heartbeat, json.dumps(body))
    t_beat = rig.clock()
    assert period_at(rig, t_beat) == "following"
    assert rig.node.heartbeats["S"] <= t_beat
    modes = [period_at(rig, t_beat + k * DT) for k in range(1, 60)]
    assert "braking" in modes and modes.index("braking") <= round(HEARTBEAT_TIMEOUT / DT)
