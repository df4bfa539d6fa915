"""Robot node over a real Zenoh bus with the simulated arm, driven by an outside client
(plain Zenoh API): states, verdicts with the request id, position jumps, hostile bodies,
the queue of one trajectory behind the running one, stop requests, the planner's death."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from drivers.robot.node import RobotNode
from drivers.robot.sim import SimRobot
from planner.bus.session import Keys, open_session
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from schemas.messages import JointTrajectory, RobotStatus
from tests.drivers.conftest import Heartbeats, raw_session, wait_for

HOME = np.array(DEFAULT_HOME)
LIMITS = Limits.ur_default()


def smooth_move(
    q0: np.ndarray,
    dq: np.ndarray,
    duration: float,
    rate: float = 500.0,
    id: str | None = None,
    session: str | None = None,
) -> JointTrajectory:
    """Minimum-jerk move from q0 to q0 + dq (rest at both ends), sampled at ``rate``."""
    t = np.arange(0.0, duration + 0.5 / rate, 1.0 / rate)
    x = t / duration
    s = 10 * x**3 - 15 * x**4 + 6 * x**5
    sd = (30 * x**2 - 60 * x**3 + 30 * x**4) / duration
    sdd = (60 * x - 180 * x**2 + 120 * x**3) / duration**2
    return JointTrajectory(
        robot="arm0",
        id=id,
        session=session,
        t=t.tolist(),
        names=list(JOINT_NAMES_UR),
        q=(q0 + s[:, None] * dq).tolist(),
        qd=(sd[:, None] * dq).tolist(),
        qdd=(sdd[:, None] * dq).tolist(),
    )


class Recorder:
    """Collects decoded JSON bodies of one key."""

    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []

    def __call__(self, sample: Any) -> None:
        self.items.append(json.loads(sample.payload.to_bytes()))


class Cell:
    """A simulated arm's driver on the bus (its laser gate on ``gate_output``, if any) and an
    outside client (plain Zenoh) playing the planner: liveliness token, heartbeats of session
    ``name``, recorders of the driver's joint states, status and ``<prefix>/laser``."""

    def __init__(
        self, endpoint: str, keys: Keys, name: str = "planner-A", *, beat: bool = True,
        require_planner: bool = True, q0: np.ndarray = HOME, gate_output: int | None = None,
    ) -> None:  # fmt: skip
        self.keys, self.name = keys, name
        self.client = raw_session(endpoint)
        self.states, self.statuses, self.lasers = Recorder(), Recorder(), Recorder()
        self._subs = [
            self.client.declare_subscriber(keys.joint_states("arm0"), self.states),
            self.client.declare_subscriber(keys.status("arm0"), self.statuses),
            self.client.declare_subscriber(keys.laser, self.lasers),
        ]
        self.token = self.client.liveliness().declare_token(keys.alive("planner"))
        self.beats = Heartbeats(self.client, keys.prefix, name) if beat else None
        self.session = open_session(listen=False, endpoint=endpoint)
        self.sim = SimRobot(JOINT_NAMES_UR, q0, LIMITS)
        self.node = RobotNode(self.session, keys, "arm0", self.sim, LIMITS,
                              require_planner=require_planner, gate_output=gate_output).start()  # fmt: skip
        wait_for(lambda: self.node.planner_alive and len(self.states.items) > 5, what="states")

    def send(self, traj: JointTrajectory | dict[str, Any] | bytes) -> None:
        if isinstance(traj, JointTrajectory):
            traj = traj.model_dump_json().encode()
        body = traj if isinstance(traj, bytes) else json.dumps(traj).encode()
        self.client.put(self.keys.trajectory("arm0"), body)

    def acks(self) -> list[dict[str, Any]]:
        """Distinct verdicts in the order the driver published them."""
        out: list[dict[str, Any]] = []
        for s in list(self.statuses.items):
            a = s.get("trajectory")
            if a is not None and (not out or a != out[-1]):
                out.append(a)
        return out

    def ack(self, id: str, timeout: float = 10.0) -> dict[str, Any]:
        wait_for(lambda: any(a["id"] == id for a in self.acks()), timeout, f"verdict on {id}")
        return next(a for a in self.acks() if a["id"] == id)

    def q(self) -> np.ndarray:
        return np.asarray(self.states.items[-1]["q"])

    def at_rest(self) -> bool:
        return self.states.items[-1]["qd"] == [0.0] * 6 and self.sim.measured().mode in (
            "idle", "stopped")  # fmt: skip

    def close(self) -> None:
        self.node.stop()
        self.session.close()
        if self.beats is not None:
            self.beats.stop()
        for s in self._subs:
            s.undeclare()
        self.token.undeclare()
        self.client.close()


@pytest.fixture
def cell(hub: Any, endpoint: str, keys: Keys) -> Iterator[Cell]:
    c = Cell(endpoint, keys)
    yield c
    c.close()


def test_follows_trajectory_acks_with_the_request_id(cell: Cell) -> None:
    off = np.array([0, 0, 0.05, 0, 0, 0])
    far = smooth_move(HOME + off, np.full(6, 0.1), 0.5, id="far", session=cell.name)
    cell.send(far)
    ack = cell.ack("far")
    assert ack["accepted"] is False
    assert ack["reason"] == (
        "q[0]: starts 0.0500 rad from the current state on joint elbow (tolerance 0.01 rad)"
    )
    assert any(
        (s["fault"] or "").startswith("trajectory rejected: q[0]") for s in cell.statuses.items
    )
    np.testing.assert_allclose(cell.q(), HOME, atol=1e-12)

    dq = np.array([0.1, -0.05, 0.05, 0.1, -0.1, 0.2])
    cell.send(smooth_move(HOME, dq, 0.6, id="req-7", session=cell.name))
    ack = cell.ack("req-7")
    assert ack["accepted"] is True and ack["reason"] is None
    wait_for(
        lambda: cell.node.n_accepted == 1 and cell.at_rest() and cell.sim.measured().mode == "idle"
    )
    np.testing.assert_allclose(cell.q(), HOME + dq, atol=1e-9)
    # the verdict is repeated in every later status
    first = next(
        i for i, s in enumerate(cell.statuses.items) if (s["trajectory"] or {}).get("id") == "req-7"
    )
    later = cell.statuses.items[first:]
    assert len(later) > 3 and all(s["trajectory"] == ack for s in later)
    assert all(s["fault"] is None for s in later)
    modes = {RobotStatus.model_validate(s).mode for s in cell.statuses.items}
    assert {"idle", "following"} <= modes
    mid = [s for s in cell.states.items if np.allclose(s["q"], HOME + dq / 2, atol=2e-3)]
    assert mid, "joint states never passed the trajectory midpoint"


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; a rerun is listed by -rR
def test_joint_states_at_250_hz(cell: Cell) -> None:
    """A real-time probe: the driver publishes joint states every 4 ms (SPEC: >= 100 Hz).
    Counted by the states' own stamps over one second of the driver's clock, once a state
    stamped after it has arrived: a receive thread running behind in this process (it shares
    the GIL with the driver) no longer reads as states the driver did not publish."""
    t_a = cell.states.items[-1]["t"]
    wait_for(lambda: cell.states.items[-1]["t"] > t_a + 1.0, 5.0, "a second of joint states")
    t = np.array([s["t"] for s in list(cell.states.items)])
    t = t[(t > t_a) & (t <= t_a + 1.0)]
    dt = np.diff(t)
    print(f"joint states: {t.size} in 1 s of driver stamps, median gap "
          f"{1e3 * np.median(dt):.2f} ms, p99 {1e3 * np.percentile(dt, 99):.2f} ms, max "
          f"{1e3 * dt.max():.2f} ms (period 4 ms)")  # fmt: skip
    assert np.median(dt) == pytest.approx(1 / 250.0, rel=0.1)
    assert t.size >= 0.9 * 250 and np.percentile(dt, 99) < 0.010  # SPEC: >= 100 Hz


def test_position_jump_is_refused_and_the_arm_never_moves(cell: Cell) -> None:
    traj = smooth_move(HOME, np.zeros(6), 0.2, id="jump", session=cell.name)
    q = np.asarray(traj.q)
    q[12:, 5] += 0.5  # wrist_3: 0.5 rad in one 2 ms step, qd = qdd = 0 declared
    cell.send(traj.model_copy(update={"q": q.tolist()}))
    ack = cell.ack("jump")
    assert not ack["accepted"]
    assert (
        ack["reason"] == "q[12]: wrist_3 moves 0.5000 rad in 0.0020 s = 250.0 rad/s > 3.1416 rad/s"
    )
    time.sleep(0.1)
    assert max(np.abs(np.asarray(s["q"]) - HOME).max() for s in cell.states.items) == 0.0


def test_hostile_and_oversized_bodies_are_refused_and_the_driver_keeps_serving(
    cell: Cell,
) -> None:
    big = b'{"schema":"beamrelay.trajectory/1","robot":"arm0","t":[' + b"0," * (2_200_000) + b"0]}"
    bodies = [
        (big, f"body: payload of {len(big)} bytes exceeds 4194304 bytes"),
        (b"\x00\xff", "body: invalid JSON"),
        (b'{"schema":"beamrelay.trajectory/1","robot":"arm0","t":[0],"names":[],"q":[[1'
         + b"0" * 5000 + b"]],\"qd\":[[0]],\"qdd\":[[0]]}", "q[0][0]: expected a number, got a 5001-digit integer"),
        (b'{"schema":"beamrelay.trajectory/1","robot":"arm0","id":"x","t":[0, NaN],'
         b'"names":[],"q":[[],[]],"qd":[[],[]],"qdd":[[],[]]}', "t[1]: "),
    ]  # fmt: skip
    assert len(big) > 4 * 1024 * 1024
    for n, (body, reason) in enumerate(bodies, start=1):
        cell.send(body)
        wait_for(lambda n=n: cell.node.n_rejected == n, what=f"rejection {n}")
        wait_for(lambda reason=reason: bool(acks := cell.acks())
                 and acks[-1]["reason"].startswith(reason), what=reason)  # fmt: skip
    assert cell.node.intake.n_oversized == 1
    cell.send(smooth_move(HOME, np.full(6, 0.02), 0.3, id="after", session=cell.name))
    assert cell.ack("after")["accepted"]


@pytest.mark.serial  # a real-time probe: stop request to rest < 300 ms (the stop's rules
# on a simulated clock: test_watchdog.py)
def test_stop_brakes_refuses_earlier_trajectories_then_accepts_a_new_one(cell: Cell) -> None:
    # 8500 samples (3.5 MB): still being parsed when the stop arrives right after it
    late = smooth_move(HOME, np.full(6, 0.01), 17.0, id="late", session=cell.name)
    late_body = late.model_dump_json().encode()
    dq = np.array([0, 0, 0, 0.8, 0.8, 0.8])  # 3 s, peak 0.5 rad/s: the stop comes mid-move
    cell.send(smooth_move(HOME, dq, 3.0, id="A", session=cell.name))
    wait_for(lambda: np.max(np.abs(cell.states.items[-1]["qd"])) > 0.3, what="motion")
    before = cell.node.intake.n_received
    cell.send(late_body)
    # the stop must come after the driver received the body (a 3.5 MB body can reach it
    # after a stop put later on a loaded machine: then it is judged as sent after it)
    wait_for(lambda: cell.node.intake.n_received > before, what="the late body received")
    t_stop = time.time()
    cell.client.put(cell.keys.stop, b"\x00 anything at all")
    wait_for(lambda: cell.states.items[-1]["t"] > t_stop and cell.at_rest(), 5.0, "arm at rest")
    rest = next(s["t"] for s in cell.states.items if s["t"] > t_stop and s["qd"] == [0.0] * 6)
    print(f"stop request to rest: {1e3 * (rest - t_stop):.0f} ms")
    assert rest - t_stop < 0.3
    assert cell.sim.measured().mode == "stopped"
    ack = cell.ack("late", timeout=20)
    assert not ack["accepted"]
    assert ack["reason"] == f"body: received before the stop requested on {cell.keys.stop}"
    wait_for(lambda: any("stop requested" in (s["fault"] or "") for s in cell.statuses.items))
    q_rest = cell.q()
    assert np.abs(q_rest - (HOME + dq)).max() > 0.05  # stopped short of A's end
    cell.send(smooth_move(q_rest, np.full(6, -0.05), 0.5, id="new", session=cell.name))
    assert cell.ack("new")["accepted"]
    wait_for(
        lambda: cell.node.n_accepted == 2 and cell.at_rest() and cell.sim.measured().mode == "idle"
    )
    np.testing.assert_allclose(cell.q(), q_rest - 0.05, atol=1e-9)


PLANNER = """
import json, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"peer"')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
s = zenoh.open(conf)
token = s.liveliness().declare_token(sys.argv[2] + "/alive/planner")
pub = s.declare_publisher(sys.argv[2] + "/heartbeat")
print("ready", flush=True)
seq = 0
while True:
    pub.put(json.dumps({"schema": "beamrelay.heartbeat/1", "t": time.time(),
                        "session": sys.argv[3], "seq": seq}))
    seq += 1
    time.sleep(0.01)
"""


def start_planner(endpoint: str, keys: Keys, name: str) -> subprocess.Popen[bytes]:
    """An outside planner process: liveliness token and 100 Hz heartbeats of ``name``."""
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    p = subprocess.Popen([sys.executable, "-c", PLANNER, endpoint, keys.prefix, name],
                         stdout=subprocess.PIPE, env=env)  # fmt: skip
    assert p.stdout is not None and p.stdout.readline().strip() == b"ready"
    return p


@pytest.mark.serial
def test_planner_killed_arm_stops_within_100_ms(hub: Any, endpoint: str, keys: Keys) -> None:
    """The liveliness token is an extra trigger: a SIGKILLed planner's token goes within
    milliseconds, before its heartbeat's 100 ms timeout."""
    planner = start_planner(endpoint, keys, "P1")
    cell = Cell(endpoint, keys, "P1", beat=False)
    cell.token.undeclare()  # only the planner process's token
    try:
        wait_for(lambda: "P1" in cell.node.heartbeats, what="heartbeats")
        dq = np.array([0.0, 0.0, 0.0, 0.3, 0.3, 0.3])  # peak 0.28 rad/s over 2 s
        cell.send(smooth_move(HOME, dq, 2.0, id="A", session="P1"))
        wait_for(lambda: np.max(np.abs(cell.states.items[-1]["qd"])) > 0.1, what="motion")
        killed = time.time()
        planner.send_signal(signal.SIGKILL)
        wait_for(lambda: cell.node.planner_lost_at is not None, what="planner loss")
        wait_for(lambda: cell.states.items[-1]["qd"] == [0.0] * 6, what="arm at rest")
        lost = cell.node.planner_lost_at
        assert lost is not None
        after = [s for s in cell.states.items if s["t"] >= lost]
        v = np.array([np.max(np.abs(s["qd"])) for s in after])
        stopped = after[int(np.argmax(v == 0.0))]["t"]
        print(f"token loss seen {1e3 * (lost - killed):.1f} ms after SIGKILL, "
              f"at rest {1e3 * (stopped - lost):.1f} ms later")  # fmt: skip
        assert stopped - lost <= 0.100 + 0.010  # brake time + one state period + scheduling
        assert np.all(np.diff(v) <= 1e-9)  # monotone deceleration, no overshoot
        q_now = cell.q()
        cell.send(smooth_move(q_now, np.full(6, 0.01), 0.5, id="B", session="P1"))
        assert cell.ack("B")["reason"] == "body: no planner alive (watchdog): not moving"
    finally:
        planner.kill()
        planner.wait()
        cell.token = cell.client.liveliness().declare_token(keys.alive("other"))
        cell.close()


def test_a_dead_parse_worker_is_replaced(cell: Cell) -> None:
    worker = cell.node.intake._worker
    assert worker is not None
    worker.proc.kill()
    worker.proc.wait(5)
    cell.send(smooth_move(HOME, np.full(6, 0.02), 0.3, id="lost", session=cell.name))
    wait_for(lambda: cell.node.n_rejected == 1, what="rejection")
    assert cell.acks()[-1]["reason"].startswith("body: parse worker failed")
    cell.send(smooth_move(HOME, np.full(6, 0.02), 0.3, id="next", session=cell.name))
    assert cell.ack("next")["accepted"]
    assert cell.node.intake.n_restarts == 1
