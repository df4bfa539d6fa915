"""The laser gate in the robot driver: off at start-up, on exactly in the trajectory's
laser_on intervals, forced off on a stop request, a lost heartbeat or a fault, recorded
with its switching figures; the UR backend's digital output through RTDE IO (fake, calls
recorded with times); the simulated camera sees the spot only while the gate is on."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from drivers.robot.follower import Reference, TrajectoryFollower
from drivers.robot.node import RobotNode
from drivers.robot.sim import MAX_CATCH_UP
from drivers.robot.ur import URRobot
from drivers.robot.ur_fake import FakeURController
from planner.bus.session import Keys, open_session
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests.drivers.conftest import Heartbeats, raw_session, wait_for
from tests.drivers.robot.test_robot_node import Cell, smooth_move

HOME = np.array(DEFAULT_HOME)
LIMITS = Limits.ur_default()
DT = 1 / 500.0
DQ = np.array([0.1, -0.05, 0.05, 0.1, -0.1, 0.2])


def test_reference_edges_and_follower_modes() -> None:
    m = smooth_move(HOME, DQ, 1.0)
    t = np.asarray(m.t) + 5.0  # a reference need not start at 0
    ref = Reference(t, np.asarray(m.q), np.asarray(m.qd), np.asarray(m.qdd),
                    np.array([[5.2, 5.4], [5.6, 5.6]]))  # fmt: skip
    assert ref.laser_edge(0.1) is None and ref.laser_edge(0.2) == pytest.approx(0.2)
    assert ref.laser_edge(0.4) == pytest.approx(0.2) and ref.laser_edge(0.401) is None
    assert ref.laser_edge(0.6) == pytest.approx(0.6) and ref.laser_edge(0.61) is None
    f = TrajectoryFollower(HOME, LIMITS, DT)
    f.follow(ref)
    on = []
    for _ in range(700):
        f.step()
        on.append((f.mode, f.tau, f.laser_edge() is not None))
    lit = [(mode, tau) for mode, tau, g in on if g]
    assert {mode for mode, _ in lit} == {"following"}  # never while approaching or settling
    taus = np.array([tau for _, tau in lit])
    # on from 0.2 s to 0.4 s (101 periods) and the single period at 0.6 s
    assert (
        len(taus) == 102 and taus.min() == pytest.approx(0.2) and taus.max() == pytest.approx(0.6)
    )


class GateCell(Cell):
    """The simulated arm's driver with a gate on output 2 and an outside client playing the
    planner (plain Zenoh) as session ``P``, recording the status and ``<prefix>/laser``."""

    def __init__(self, endpoint: str, keys: Keys, gate_output: int | None = 2) -> None:
        super().__init__(endpoint, keys, "P", gate_output=gate_output)
        wait_for(lambda: "P" in self.node.heartbeats, what="planner")


@pytest.fixture
def cell(hub: Any, endpoint: str, keys: Keys) -> Iterator[GateCell]:
    c = GateCell(endpoint, keys)
    yield c
    c.close()


def _move(duration: float, laser_on: list[list[float]] | None, id: str) -> dict[str, Any]:
    body = json.loads(smooth_move(HOME, DQ, duration, id=id, session="P").model_dump_json())
    body["laser_on"] = laser_on
    return body


def _edges(items: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The published LaserStates where ``on`` changed (the first one counts as a change)."""
    return [m for i, m in enumerate(items) if i == 0 or m["on"] != items[i - 1]["on"]]


@pytest.mark.serial
def test_gate_plays_the_intervals(cell: GateCell) -> None:
    # off at start-up, commanded before the loop runs
    assert cell.sim.gate_calls[0][1] is False
    wait_for(lambda: any(m["reason"] == "start-up" for m in cell.lasers.items) or
             cell.lasers.items != [], what="laser state")  # fmt: skip
    cell.send(_move(0.8, [[0.2, 0.5]], "lit"))
    wait_for(lambda: cell.node.ack is not None, what="verdict")
    assert cell.node.ack is not None and cell.node.ack.accepted, cell.node.ack
    wait_for(lambda: len(cell.node.gate.switches) >= 2, what="two switches")  # type: ignore[union-attr]
    on, off = cell.node.gate.switches[:2]  # type: ignore[union-attr]
    assert on.on and not off.on
    # switched in the loop iteration that plays the edge: in trajectory time the lag is 0
    # to 1 period, more only when the sim caught up missed periods (a loaded machine)
    assert on.edge == pytest.approx(0.2) and -1e-6 < on.lag <= MAX_CATCH_UP * DT
    assert off.edge == pytest.approx(0.5) and 0 < off.lag <= MAX_CATCH_UP * DT
    assert 0 <= on.latency < 0.05 and 0 <= off.latency < 0.05  # s from the period's start
    calls = [c for c in cell.sim.gate_calls if c[0] > 0]
    switched = [
        (t, s) for (t, s), (_, prev) in zip(calls[1:], calls[:-1], strict=True) if s != prev
    ]
    assert [s for _, s in switched] == [True, False]
    # on the wall clock the gate is on for the interval's 0.3 s (the sim runs in real time)
    assert switched[1][0] - switched[0][0] == pytest.approx(0.3, abs=0.05)
    # every status republishes the state (same ``on``, same reason): the switches are the
    # messages where ``on`` changes
    wait_for(lambda: [m["on"] for m in _edges(cell.lasers.items)] == [False, True, False],
             what="published switches")  # fmt: skip
    _, lit, dark = _edges(cell.lasers.items)
    assert lit["reason"] == "laser_on interval" and dark["reason"] == "interval ended"
    assert lit["lag"] == pytest.approx(on.lag) and dark["lag"] == pytest.approx(off.lag)
    assert all(m["output"] == 2 for m in cell.lasers.items)
    wait_for(lambda: cell.statuses.items and cell.statuses.items[-1]["laser_on"] is False)


@pytest.mark.serial
def test_stop_request_forces_the_gate_off(cell: GateCell) -> None:
    cell.send(_move(3.0, [[0.1, 2.9]], "long"))
    wait_for(lambda: cell.sim.gate, what="gate on")
    sent = time.monotonic()
    cell.client.put(cell.keys.stop, b"anything")
    wait_for(lambda: not cell.sim.gate, timeout=2.0, what="gate off")
    t_off = next(t for t, s in reversed(cell.sim.gate_calls) if not s)
    print(
        f"stop sent to gate off: {1e3 * (t_off - sent):.1f} ms (the next period on a "
        "simulated clock: test_watchdog.py)"
    )
    assert t_off - sent < 0.3  # forced off in the period that handles the stop
    last = cell.node.gate.switches[-1]  # type: ignore[union-attr]
    assert not last.on and last.reason.startswith("stop requested")
    time.sleep(0.2)  # braking, then stopped: it stays off
    assert not cell.sim.gate and cell.sim.measured().mode in ("braking", "stopped")


@pytest.mark.parametrize(
    ("laser_on", "reason"),
    [
        ([[0.5, 0.2]], "laser_on[0]: ends"),
        ([[0.1, 0.3], [0.2, 0.4]], "laser_on[1]: intervals must be in order"),
        ([[0.1, 9.0]], "laser_on[0]: [0.1, 9] s is outside"),
        ([[0.1]], "laser_on[0]"),
        ("on", "laser_on"),
        ([[0.1, 1e400]], "laser_on[0][1]"),
    ],
)
def test_malformed_laser_on_is_refused(cell: GateCell, laser_on: Any, reason: str) -> None:
    body = json.dumps(_move(0.5, None, "bad")).replace('"laser_on": null',
                                                      f'"laser_on": {json.dumps(laser_on)}')  # fmt: skip
    body = body.replace("Infinity", "1e400")
    cell.send(body.encode())
    wait_for(lambda: cell.node.n_rejected == 1, what="rejection")
    assert cell.node.ack is not None and cell.node.ack.reason is not None
    assert cell.node.ack.reason.startswith(reason), cell.node.ack.reason
    assert not any(s for _, s in cell.sim.gate_calls)


def test_laser_on_to_a_driver_without_gate_is_refused(hub: Any, endpoint: str, keys: Keys
                                                      ) -> None:  # fmt: skip
    c = GateCell(endpoint, keys, gate_output=None)
    try:
        c.send(_move(0.5, [[0.1, 0.2]], "nogate"))
        wait_for(lambda: c.node.n_rejected == 1, what="rejection")
        assert c.node.ack is not None and "switches no laser gate" in str(c.node.ack.reason)
        assert c.sim.gate_calls == [] and c.node.gate is None
        c.send(_move(0.5, None, "plain"))  # without laser_on it moves as before
        wait_for(lambda: c.node.n_accepted == 1, what="acceptance")
    finally:
        c.close()


def _ur(
    gate_output: int | None = 3,
) -> tuple[URRobot, FakeURController, list[tuple[float, int, bool]], list[str]]:
    """A UR backend on the simulated controller; gate IO calls and the order of gate and
    servoStop calls are recorded."""
    fake = FakeURController(HOME)
    io_calls: list[tuple[float, int, bool]] = []
    order: list[str] = []
    servo_stop = fake.servoStop

    def recorded_stop(*a: Any) -> bool:
        order.append("servoStop")
        return servo_stop(*a)

    fake.servoStop = recorded_stop  # type: ignore[method-assign]

    class FakeIO:
        def setStandardDigitalOut(self, output: int, state: bool) -> bool:
            io_calls.append((time.monotonic(), output, state))
            order.append("setStandardDigitalOut")
            return True

    robot = URRobot("fake", JOINT_NAMES_UR, LIMITS, control=fake, receive=fake,
                    gate_output=gate_output, io=FakeIO())  # fmt: skip
    return robot, fake, io_calls, order


def test_ur_gate_output_switches_and_goes_off_on_a_fault_and_at_exit() -> None:
    robot, fake, io, order = _ur()
    robot.set_gate(True)
    assert io == []  # queued: written by the next period, from a helper thread
    robot.begin_period()
    robot.step()
    robot.end_period()
    robot.io_call.wait(1.0)
    assert [(o, s) for _, o, s in io] == [(3, True)] and robot.gate_calls[0][1:] == (3, True)
    m = smooth_move(HOME, DQ, 0.5)
    robot.command(Reference(*(np.asarray(a, dtype=float) for a in (m.t, m.q, m.qd, m.qdd))))
    for _ in range(20):
        robot.begin_period()
        robot.step()
        robot.end_period()
    fake.protective_stop()
    for _ in range(5):
        robot.begin_period()
        robot.step()
        robot.end_period()
    robot.call.wait(1.0)
    assert [(o, s) for _, o, s in io][-1] == (3, False)  # entering the fault: off ...
    i_off = order.index("setStandardDigitalOut", 1)  # the first switch after the "on"
    assert "servoStop" in order[i_off + 1 :]  # ... before the servo stops
    robot.close()
    assert [(o, s) for _, o, s in io][-1] == (3, False)
    times = [t for t, _, _ in io]
    assert times == sorted(times)
    robot2, _, io2, _ = _ur(gate_output=None)
    robot2.set_gate(True)
    assert io2 == [] and robot2.gate_calls == []


def test_ur_node_gate_forced_off_on_a_stop(hub: Any, endpoint: str, keys: Keys) -> None:
    """Through the node with the fake RTDE: a stop request mid-mark turns the output off."""
    robot, fake, io, _ = _ur(gate_output=1)
    fake.realtime = True  # paced like a real controller: the node's loop runs in real time
    client = raw_session(endpoint)
    token = client.liveliness().declare_token(keys.alive("planner"))
    beats = Heartbeats(client, keys.prefix, "P")
    session = open_session(listen=False, endpoint=endpoint)
    node = RobotNode(session, keys, "arm0", robot, LIMITS, gate_output=1).start()
    try:
        wait_for(lambda: bool(io), what="start-up write")
        assert io[0][1:] == (1, False)  # start-up: off
        wait_for(lambda: node.planner_alive and "P" in node.heartbeats, what="planner")
        client.put(keys.trajectory("arm0"), json.dumps(_move(2.0, [[0.1, 1.9]], "m")).encode())
        wait_for(lambda: io[-1][2] is True, what="gate on")
        client.put(keys.stop, b"")
        wait_for(lambda: io[-1][2] is False, timeout=2.0, what="gate off")
    finally:
        node.stop()
        session.close()
        beats.stop()
        token.undeclare()
        client.close()
    assert io[-1][1:] == (1, False)


def test_sim_camera_sees_the_spot_only_while_the_gate_is_on() -> None:
    from drivers.camera.sim import SimCamera
    from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
    from tests.paths import SCENARIOS

    scn = load_scenario(SCENARIOS / "s_curve.yaml")
    system = system_from_scenario(scn, truth=True)
    cam = SimCamera(system, scene_objects(scn), stride=8, seed=0, gated=True)
    cam.on_joint_state("arm0", system.home)
    assert cam.spot() is None  # gated and never switched on
    cam.on_laser(True)
    lit = cam.spot()
    assert lit is not None
    cam.on_laser(False)
    assert cam.spot() is None
    free = SimCamera(system, scene_objects(scn), stride=8, seed=0)  # no gate: always lit
    free.on_joint_state("arm0", system.home)
    assert free.spot() is not None
