"""The UR backend's laser outputs: read back every period, written out of the control loop
with a timeout, configured to drop at program stop (emulated by ur_fake), all off on fault;
an RTDE socket error is a fault without a reconnect in the loop."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

from drivers.robot.ur import IO_TIMEOUT, URRobot
from drivers.robot.ur_fake import FakeURController
from planner.errors import InputError
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests.drivers.robot.test_robot_ur import period

HOME = np.array(DEFAULT_HOME)
GATE, AIM = 3, 5


def make(**kw: Any) -> tuple[URRobot, FakeURController]:
    fake = FakeURController(HOME, lag=False)
    robot = URRobot("fake", JOINT_NAMES_UR, Limits.ur_default(), control=fake, receive=fake,
                    io=fake, gate_output=GATE, aim_output=AIM, **kw)  # fmt: skip
    period(robot)
    while robot.call.busy:
        robot.call.poll()
    return robot, fake


def settle(robot: URRobot, n: int = 5) -> None:
    for _ in range(n):
        period(robot)
        time.sleep(0.002)  # the helper thread's write


def test_runstate_configured_for_every_laser_output_at_start() -> None:
    robot, fake = make()
    assert fake.runstate == {GATE: 1, AIM: 1}  # "False when program is not running"
    assert robot.runstate == {GATE: 1, AIM: 1}
    assert robot.laser_outputs == (GATE, AIM)


def test_runstate_refused_is_an_input_error_naming_laser_gate() -> None:
    fake = FakeURController(HOME)
    fake.sendCustomScriptFunction = lambda name, script: False  # type: ignore[method-assign]
    with pytest.raises(InputError) as exc:
        URRobot("fake", JOINT_NAMES_UR, Limits.ur_default(), control=fake, receive=fake,
                io=fake, gate_output=GATE)  # fmt: skip
    assert exc.value.where == "laser.gate"


def test_outputs_and_speed_are_read_back_every_period() -> None:
    robot, fake = make()
    fake.speed_scaling = 0.37
    robot.set_output(GATE, True)
    assert fake.outputs == 0  # queued, not written in the caller's thread
    settle(robot)
    m = robot.measured()
    assert m.outputs == 1 << GATE == fake.outputs
    assert m.speed == pytest.approx(0.37)
    fake._outputs_pending |= 1 << 7  # someone else switches output 7: visible in the read-back
    settle(robot, 2)
    assert robot.measured().outputs == (1 << GATE) | (1 << 7)


def test_io_call_that_does_not_return_is_a_fault_and_the_loop_keeps_its_period() -> None:
    robot, fake = make()
    release = threading.Event()
    fake.setStandardDigitalOut = lambda n, on: release.wait(5.0)  # type: ignore[method-assign]
    robot.set_output(GATE, True)
    durations = []
    end = time.monotonic() + 3 * IO_TIMEOUT
    while time.monotonic() < end:
        t0 = time.perf_counter()
        period(robot)
        durations.append(time.perf_counter() - t0)
    release.set()
    assert robot.fault == f"setStandardDigitalOut did not return within {1e3 * IO_TIMEOUT:.0f} ms"
    # never waited for the hung call: that one hangs 5 s, every period returned long before
    # (not a period bound: this runs beside other tests, and a preempted period once took
    # 261 ms; the control period itself is measured in the serial real-time probes)
    assert max(durations) < 1.0, max(durations)


def test_fault_switches_every_laser_output_off() -> None:
    robot, fake = make()
    robot.set_output(GATE, True)
    robot.set_output(AIM, True)
    settle(robot)
    assert fake.outputs == (1 << GATE) | (1 << AIM)
    fake.safety_mode = 5  # safeguard stop, the script still running: the driver's fault
    settle(robot)
    assert robot.fault is not None
    assert fake.outputs == 0 and robot.measured().outputs == 0


def test_close_switches_every_laser_output_off() -> None:
    robot, fake = make()
    robot.set_output(AIM, True)
    settle(robot)
    assert fake.outputs == 1 << AIM
    fake.runstate.clear()  # the controller's action would hide a missing write
    robot.close()
    fake.cycle()
    assert fake.outputs == 0


def test_watchdog_trip_drops_the_runstate_outputs_in_the_fake() -> None:
    """Deterministic cycles: 10 Hz watchdog = 50 idle cycles; the gate drops in the cycle
    the script stops, an output without runstate keeps its level."""
    fake = FakeURController(HOME)
    fake.sendCustomScriptFunction("f", f"set_runstate_standard_digital_output_to_value({GATE}, 1)")
    fake.setWatchdog(10.0)
    fake.setStandardDigitalOut(GATE, True)
    fake.setStandardDigitalOut(2, True)
    fake.cycle()
    assert fake.outputs == (1 << GATE) | (1 << 2)
    n = 0
    while fake.running:
        fake.cycle()
        n += 1
    assert n == 51  # gap > 1/10 s = 50 cycles of 2 ms
    assert fake.outputs == 1 << 2


def test_socket_error_is_a_fault_without_reconnect_in_the_loop() -> None:
    robot, fake = make()
    calls: list[str] = []

    def broken() -> list[float]:
        raise RuntimeError("read: Connection reset by peer")

    fake.getActualQ = broken  # type: ignore[method-assign]
    fake.reconnect = lambda: calls.append("reconnect")  # type: ignore[attr-defined]
    t0 = time.perf_counter()
    period(robot)
    assert time.perf_counter() - t0 < 0.01
    assert robot.fault == "RTDE link error: read: Connection reset by peer"
    assert robot.measured().mode == "fault" and robot.measured().outputs is None
    assert calls == []
