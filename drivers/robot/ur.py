"""Real UR arm through ur_rtde (backend ``ur``): ``servoJ`` at 500 Hz, states from RTDE.

Per control period (``rate``, 500 Hz on e-Series):

1. ``initPeriod()``; read the arm (``getActualQ``/``getActualQd``, rad, rad/s) and its faults
   (protective stop, emergency stop, lost connection, control script not running).
2. On a fault: ``servoStop()`` once, the follower re-synchronises to the measured joints and
   every trajectory is refused until the fault clears.
3. Otherwise the Ruckig follower (:mod:`drivers.robot.follower`) advances one period and, while it
   moves (approach, following, settle, braking), its position goes to
   ``servoJ(q, 0, 0, 1/rate, lookahead_time, gain)``; when it comes to rest the servo
   session ends with ``servoStop()``.
4. ``kickWatchdog()``: the RTDE watchdog (``setWatchdog(watchdog_hz)``) makes the
   controller stop the arm by itself if this loop stalls; ``waitPeriod()``.

Every check and watchdog of :mod:`drivers.robot.node` applies here unchanged (position-jump
and limit checks, planner heartbeat and liveliness, ``<prefix>/stop``, parsing in a worker
process): a safety stop calls :meth:`URRobot.brake`, a jerk-limited stop through ``servoJ``,
then ``servoStop``. :meth:`URRobot.close` (Ctrl-C, node exit) calls
``servoStop()`` and disconnects. The laser gate (``gate_output``) is the controller's
standard digital output of that index, set through ``RTDEIOInterface.setStandardDigitalOut``
by :meth:`URRobot.set_gate` (the node decides when); it goes off on entering a fault and
at exit. How to run it on a real arm: ``drivers/README.md``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.robot.follower import STOP_ACCELERATION, Reference, TrajectoryFollower
from drivers.robot.node import Measured
from planner.errors import InputError
from planner.model.system import Limits

LOOKAHEAD_RANGE = (0.03, 0.2)  # s, accepted by servoJ
GAIN_RANGE = (100.0, 2000.0)  # servoJ proportional gain
MOVING = ("approach", "following", "settle", "braking")


class URRobot:
    """A UR arm behind RTDE, for :class:`drivers.robot.node.RobotNode`.

    ``control``/``receive`` default to ``rtde_control.RTDEControlInterface(host, rate)`` and
    ``rtde_receive.RTDEReceiveInterface(host, rate)``; tests pass objects with the same
    methods.
    """

    kind = "ur"

    def __init__(
        self,
        host: str,
        names: tuple[str, ...],
        limits: Limits,
        *,
        rate: float = 500.0,
        lookahead_time: float = 0.1,
        gain: float = 300.0,
        watchdog_hz: float = 10.0,
        stop_acceleration: float = STOP_ACCELERATION,
        control: Any = None,
        receive: Any = None,
        gate_output: int | None = None,
        io: Any = None,
    ) -> None:
        if not LOOKAHEAD_RANGE[0] <= lookahead_time <= LOOKAHEAD_RANGE[1]:
            raise InputError(
                f"must be in {list(LOOKAHEAD_RANGE)} s, got {lookahead_time}", "--lookahead"
            )
        if not GAIN_RANGE[0] <= gain <= GAIN_RANGE[1]:
            raise InputError(f"must be in {list(GAIN_RANGE)}, got {gain}", "--gain")
        self.names = tuple(names)
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        self.lookahead_time = lookahead_time
        self.gain = gain
        if control is None or receive is None:
            control, receive = _connect(host, self.rate)
        self.control = control
        self.receive = receive
        self.gate_output = gate_output
        if gate_output is not None and io is None:
            io = _connect_io(host)
        self.io = io
        self.gate_calls: list[tuple[float, int, bool]] = []  # (monotonic s, output, state)
        self.control.setWatchdog(watchdog_hz)
        self.follower = TrajectoryFollower(
            np.asarray(self.receive.getActualQ(), dtype=float), limits, self.dt, stop_acceleration
        )
        self.servoing = False
        self.fault: str | None = None
        self.protective_stop = False
        self._t0: Any = None
        self._last = Measured(self.follower.q.copy(), np.zeros(len(self.names)), "idle")

    # -- period ---------------------------------------------------------------------------
    def begin_period(self) -> None:
        self._t0 = self.control.initPeriod()

    def step(self) -> Measured:
        q = np.asarray(self.receive.getActualQ(), dtype=float)
        qd = np.asarray(self.receive.getActualQd(), dtype=float)
        fault = self._read_fault()
        if fault is not None:
            if self.fault is None:  # entering the fault: laser off, stop servoing once
                self.set_gate(False)
                self._servo_stop()
                self.follower.reset(q)
            self.fault = fault
        elif self.fault is not None:  # fault cleared (e.g. protective stop released)
            self.fault = None
            self.follower.reset(q)
        if self.fault is None:
            cmd = self.follower.step()
            if cmd.mode in MOVING:
                ok = self.control.servoJ(
                    cmd.q.tolist(), 0.0, 0.0, self.dt, self.lookahead_time, self.gain
                )
                self.servoing = True
                if ok is False:
                    self.fault = "servoJ refused the command"
                    self._servo_stop()
                    self.follower.reset(q)
            elif self.servoing:
                self._servo_stop()
        self.control.kickWatchdog()
        mode = "fault" if self.fault else self.follower.mode
        self._last = Measured(q, qd, mode, self.protective_stop, self.fault)
        return self._last

    def end_period(self) -> None:
        self.control.waitPeriod(self._t0)

    def _read_fault(self) -> str | None:
        self.protective_stop = bool(self.receive.isProtectiveStopped())
        if self.protective_stop:
            return "protective stop"
        if self.receive.isEmergencyStopped():
            return "emergency stop"
        if not (self.control.isConnected() and self.receive.isConnected()):
            return "RTDE connection lost"
        if not self.control.isProgramRunning():
            return "RTDE control script not running (remote control off or watchdog tripped)"
        return None

    def _servo_stop(self) -> None:
        self.control.servoStop()
        self.servoing = False

    # -- commands (called by the node's control loop, between periods) -----------------------
    def measured(self) -> Measured:
        return self._last

    def command(self, reference: Reference) -> None:
        if self.fault is not None:
            raise InputError(f"arm in fault: {self.fault}", "robot")
        if not self.servoing:  # start from where the arm really is
            self.follower.reset(self._last.q)
        self.follower.follow(reference)

    def queue(self, reference: Reference) -> None:
        """Start ``reference`` when the running trajectory reaches its last sample."""
        if self.fault is not None:
            raise InputError(f"arm in fault: {self.fault}", "robot")
        self.follower.enqueue(reference)

    def brake(self, reason: str) -> None:
        self.follower.brake()

    def set_gate(self, on: bool) -> None:
        """The laser gate: standard digital output ``gate_output`` through RTDE IO (no-op
        without one). Every command is recorded with its monotonic time."""
        if self.gate_output is None or self.io is None:
            return
        import time

        self.io.setStandardDigitalOut(self.gate_output, bool(on))
        self.gate_calls.append((time.monotonic(), self.gate_output, bool(on)))
        del self.gate_calls[:-4096]

    def close(self) -> None:
        """Ctrl-C / exit: laser off, stop servoing and disconnect."""
        self.set_gate(False)
        self._servo_stop()
        self.control.disconnect()
        self.receive.disconnect()


def _connect(host: str, rate: float) -> tuple[Any, Any]:
    """Open the RTDE control and receive interfaces (InputError when the arm is unreachable)."""
    from rtde_control import RTDEControlInterface
    from rtde_receive import RTDEReceiveInterface

    try:
        receive = RTDEReceiveInterface(host, rate)
        control = RTDEControlInterface(host, rate)
    except RuntimeError as exc:  # ur_rtde raises RuntimeError on connection failures
        raise InputError(f"cannot connect to the UR controller: {exc}", f"--host {host}") from exc
    return control, receive


def _connect_io(host: str) -> Any:
    """The RTDE IO interface that drives the laser gate output (InputError when unreachable)."""
    from rtde_io import RTDEIOInterface

    try:
        return RTDEIOInterface(host)
    except RuntimeError as exc:
        raise InputError(
            f"cannot open RTDE IO on the UR controller: {exc}", f"--host {host}"
        ) from exc
