"""The planner heartbeat, driver side: a hung planner whose token lingers (and a fake second
token, and another session's heartbeats) cannot keep the arm moving (a real-time probe on
the bus); bench work needs none. The watchdog's rules on a simulated clock are in
test_watchdog.py."""

from __future__ import annotations

import json
import signal
import sys
import time
from typing import Any

import numpy as np
import pytest

from drivers.robot.follower import STOP_ACCELERATION, STOP_JERK
from drivers.robot.node import HEARTBEAT_TIMEOUT, PERIOD_LOG, RobotNode
from drivers.robot.sim import SimRobot
from planner.bus.session import Keys, open_session
from planner.model.system import JOINT_NAMES_UR
from tests.drivers.conftest import wait_for
from tests.drivers.robot.test_robot_node import HOME, LIMITS, Cell, smooth_move, start_planner


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; -rR lists a rerun
def test_sigstopped_planner_stops_the_arm_despite_fake_token_and_foreign_heartbeats(
    hub: Any, endpoint: str, keys: Keys
) -> None:
    """The planner process is SIGSTOPped mid-move: its liveliness token stays for the Zenoh
    lease (~9 s), the test's client holds a second ``alive/planner`` token and beats as
    session "intruder"; the arm must be at rest within 300 ms of the planner's last
    heartbeat."""
    planner = start_planner(endpoint, keys, "P1")
    cell = Cell(endpoint, keys, "intruder")  # fake token + 100 Hz heartbeats of another session
    beats: list[dict[str, Any]] = []
    sub = cell.client.declare_subscriber(
        keys.heartbeat, lambda s: beats.append(json.loads(s.payload.to_bytes()))
    )
    try:
        wait_for(lambda: "P1" in cell.node.heartbeats, what="planner heartbeats")
        dq = np.array([0, 0, 0, 0.8, 0.8, 0.8])  # min-jerk: peak 1.25 rad/s at 0.75 s
        cell.send(smooth_move(HOME, dq, 1.5, id="A", session="P1"))
        assert cell.ack("A")["accepted"]
        wait_for(lambda: np.max(np.abs(cell.states.items[-1]["qd"])) > 0.8, what="fast motion")
        planner.send_signal(signal.SIGSTOP)
        wait_for(cell.at_rest, 3.0, "arm at rest")
        last = max(b["t"] for b in beats if b["session"] == "P1")
        rest = next(s["t"] for s in cell.states.items if s["t"] > last and s["qd"] == [0.0] * 6)
        after = [s for s in cell.states.items if s["t"] > last]
        v0 = np.max(np.abs(after[0]["qd"]))
        brake = v0 / STOP_ACCELERATION + STOP_ACCELERATION / STOP_JERK
        print(f"heartbeat loss to rest: {1e3 * (rest - last):.0f} ms (timeout "
              f"{1e3 * HEARTBEAT_TIMEOUT:.0f} ms + brake {1e3 * brake:.0f} ms from {v0:.2f} rad/s)")  # fmt: skip
        assert rest - last < 0.300
        assert rest - last > HEARTBEAT_TIMEOUT  # it was the heartbeat, not something sooner
        assert cell.node.planner_alive  # both tokens still there
        assert np.abs(cell.q() - (HOME + dq)).max() > 0.1  # stopped mid-move
        assert cell.node.stopped_by is not None
        assert cell.node.stopped_by.startswith("planner heartbeat lost: session P1 silent for")
        # trajectories of the hung session are refused; the intruder's beats do not help
        cell.send(smooth_move(cell.q(), np.full(6, 0.01), 0.3, id="B", session="P1"))
        assert cell.ack("B")["reason"].startswith(
            "session: no heartbeat from planner session P1 within 100 ms (last: "
        )
    finally:
        planner.send_signal(signal.SIGCONT)
        planner.kill()
        planner.wait()
        sub.undeclare()
        cell.close()


def test_without_require_planner_no_session_or_heartbeat_is_needed(
    hub: Any, endpoint: str, keys: Keys
) -> None:
    """Bench work (``--no-require-planner``): no token, no heartbeat, no session."""
    cell = Cell(endpoint, keys, beat=False, require_planner=False)
    cell.token.undeclare()
    cell.token = cell.client.liveliness().declare_token(keys.alive("bench"))
    try:
        dq = np.full(6, 0.05)
        cell.send(smooth_move(HOME, dq, 0.4, id="bench"))
        assert cell.ack("bench")["accepted"]
        wait_for(
            lambda: (
                cell.at_rest() and cell.node.n_accepted == 1 and cell.sim.measured().mode == "idle"
            )
        )
        np.testing.assert_allclose(cell.q(), HOME + dq, atol=1e-9)
    finally:
        cell.close()


def test_beats_that_arrive_while_the_gil_is_held_count_when_the_loop_runs(
    hub: Any, endpoint: str, keys: Keys
) -> None:
    """A Python thread of the driver's process that holds the GIL (a busy machine leaves it
    descheduled) delays every Python callback. Beats that reached the process meanwhile must
    count at the control loop's next period (Zenoh queues them without the GIL), not look as
    old as the stall: a callback would run after the loop and the arm would brake for a
    planner that never went silent."""
    planner = start_planner(endpoint, keys, "P")
    session = open_session(listen=False, endpoint=endpoint)
    node = RobotNode(session, keys, "arm0", SimRobot(JOINT_NAMES_UR, HOME, LIMITS), LIMITS).attach()

    def heard() -> bool:
        node.period()
        return "P" in node.heartbeats

    try:
        wait_for(heard, what="planner heartbeats")
        switch = sys.getswitchinterval()
        sys.setswitchinterval(10.0)  # no other thread of this process runs Python meanwhile
        try:
            t0 = time.monotonic()
            while time.monotonic() - t0 < 0.5:  # holds the GIL: 100 Hz beats keep arriving
                pass
            node.period()
        finally:
            sys.setswitchinterval(switch)
        start = node.period_starts[(node.n_periods - 1) % PERIOD_LOG]
        assert start - t0 >= 0.5
        # heard when it was sent (during the stall), not 500 ms ago: the watchdog is quiet
        assert start - node.heartbeats["P"] < HEARTBEAT_TIMEOUT
    finally:
        planner.kill()
        planner.wait()
        session.close()
