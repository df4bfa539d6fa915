"""A simulated UR controller behind the two ur_rtde interfaces, for tests, benches and
``hw check`` without a robot.

:class:`FakeURController` has the methods of ``rtde_control.RTDEControlInterface`` and
``rtde_receive.RTDEReceiveInterface`` that :class:`drivers.robot.ur.URRobot` uses (pass it as
both). What it models, per 2 ms controller cycle (one cycle per ``waitPeriod`` call):

- **Command register.** Every RTDE command of ur_rtde's control script goes through the same
  input register (``input_int_register_0``): ``servoJ`` writes 11, ``servoStop`` 16,
  ``setWatchdog`` 35 and ``kickWatchdog`` writes 0 (``NO_CMD``: ur_rtde packs the watchdog kick
  as "no command"). The script reads the register once per cycle, so the last write of a
  cycle wins. ``cycles`` records, per cycle, every write and the value the script read.
- **Servo and speed scaling.** A cycle whose register holds a servoJ makes its target the
  servo target. The arm follows the servo target as a first-order lag whose time constant
  is the servoJ ``lookahead_time`` in *controller* time; URScript time runs at the speed
  scaling ``speed_scaling`` (the pendant slider), so in real time the lag is
  ``lookahead_time / speed_scaling``: below 100 % every servoJ target is executed slower.
  ``servoStop`` ends the servo: the arm stops where it is.
- **RTDE watchdog.** After ``setWatchdog(f)``, a gap of more than ``1/f`` s between two
  register writes stops the control script (``isProgramRunning()`` false): wall time when
  ``realtime`` (the loop is paced), else controller cycles of 2 ms (deterministic tests).
- **Safety.** :meth:`protective_stop` / :meth:`emergency_stop` stop the arm and the control
  script (the controller aborts the program); :meth:`release` clears the stop (as the
  operator does on the pendant) but the script stays stopped until ``reuploadScript``.
  ``safety_mode`` follows (1 normal, 2 reduced, 3 protective stop, 5 safeguard stop, 7 robot
  emergency stop).
- **Runstate outputs.** ``sendCustomScriptFunction`` runs the
  ``set_runstate_standard_digital_output_to_value(n, state)`` calls of its script (other
  script lines are ignored); an output with state 1 ("False when program is not running") or
  3 drops at once when the control script stops: watchdog trip, protective or emergency
  stop, :meth:`stop_program`. ``output_log`` records every change of the output bits with
  its monotonic time.
- **Another process.** :func:`serve` runs a controller (cycling by itself, real-time paced)
  behind a loopback TCP port; :class:`FakeURLink` is the three RTDE interfaces of a driver
  process on it (``beamrelay robot --backend ur --host ur-fake:<port>``), so a test can
  SIGKILL the driver and watch the controller.
- **Link loss.** With ``link_alive = False`` the receive side freezes (timestamp, joints:
  ur_rtde returns the last package received) and the calls that wait for the controller
  (``servoStop``, ``setWatchdog``, ``reuploadScript``, ``disconnect``) block until the link
  returns or ``block_s`` elapse.

Joints in rad, rad/s; times in s.
"""
# long module: a fake of ur_rtde's control, receive and IO interfaces that records every call, for the tests without an arm

from __future__ import annotations

import contextlib
import datetime
import json
import re
import socket
import threading
import time
from typing import Any

import numpy as np

from planner.model.transforms import Array

CMD_NONE, CMD_SERVOJ, CMD_SERVO_STOP, CMD_SET_WATCHDOG = 0, 11, 16, 35
CYCLE = 0.002  # s, e-Series controller cycle
RUNSTATE_CALL = re.compile(
    r"set_runstate_standard_digital_output_to_value\(\s*(\d+)\s*,\s*(\d+)\s*\)"
)
LOW_WHEN_STOPPED = (1, 3)  # runstates whose output is False while the program is stopped


def pace(next_cycle: float) -> float:
    """Sleep until one controller cycle after ``next_cycle`` (monotonic s); the start of the
    next cycle (now, when already late)."""
    next_cycle += CYCLE
    delay = next_cycle - time.monotonic()
    if delay > 0:
        time.sleep(delay)
        return next_cycle
    return time.monotonic()


class FakeURController:
    """Both RTDE interfaces of a simulated UR e-Series controller (see the module docstring)."""

    def __init__(
        self,
        q0: Array,
        *,
        speed_scaling: float = 1.0,
        lag: bool = True,
        realtime: bool = False,
        block_s: float = 300.0,
    ) -> None:
        self.q = np.array(q0, dtype=float)
        self.qd = np.zeros(len(self.q))
        self.speed_scaling = speed_scaling
        self.lag = lag  # False: a perfect servo (the arm is at the last servo target)
        self.realtime = realtime
        self.block_s = block_s
        self.timestamp = 1000.0  # s since controller start
        self.cycles: list[tuple[list[int], int]] = []  # per cycle: (writes, value read)
        self.calls: list[str] = []
        self.targets: list[Array] = []  # every servoJ target sent (rad)
        self.safety_mode = 1
        self.link_alive = True
        self.connected = True
        self.running = True
        self.remote_control = True
        self.watchdog_hz = 0.0
        self.watchdog_trips = 0
        self.reuploads = 0
        self.outputs = 0  # standard digital output bits, as read back over RTDE
        self._outputs_pending = 0
        self.runstate: dict[int, int] = {}  # output -> URScript runstate (0: preserve)
        self.output_log: list[tuple[float, int]] = [(time.monotonic(), 0)]  # (s, bits)
        self._writes: list[int] = []
        self._target: Array | None = None
        self._servo_args: tuple[float, float] = (CYCLE, 0.1)  # (t, lookahead)
        self._pending: tuple[Array, tuple[float, float]] = (self.q.copy(), self._servo_args)
        self._last_write = time.monotonic()
        self._idle_cycles = 0  # cycles since the last register write
        self._frozen = (self.q.copy(), self.qd.copy(), self.timestamp)
        self._lock = threading.Lock()
        self._link = threading.Event()
        self._link.set()
        self._next = time.monotonic()

    # -- test controls ------------------------------------------------------------------
    def protective_stop(self) -> None:
        self._stop_program(3)

    def emergency_stop(self) -> None:
        self._stop_program(7)

    def safeguard_stop(self) -> None:
        self._stop_program(5)

    def release(self) -> None:
        """The operator releases the stop on the pendant; the control script stays stopped."""
        with self._lock:
            self.safety_mode = 1

    def set_link(self, alive: bool) -> None:
        with self._lock:
            self.link_alive = alive
            self._frozen = (self.q.copy(), self.qd.copy(), self.timestamp)
        if alive:
            self._link.set()
        else:
            self._link.clear()

    def _stop_program(self, mode: int) -> None:
        with self._lock:
            self.safety_mode = mode
            self._program_stopped()
            self.qd[:] = 0.0

    def stop_program(self) -> None:
        """The control script stops (stop on the pendant, dashboard ``stop``)."""
        with self._lock:
            self._program_stopped()

    def _program_stopped(self) -> None:
        """The script stops (lock held): the runstate outputs drop at once."""
        self.running = False
        self._target = None
        low = 0
        for n, state in self.runstate.items():
            if state in LOW_WHEN_STOPPED:
                low |= 1 << n
        self._outputs_pending &= ~low
        self._set_outputs(self.outputs & ~low)

    def _set_outputs(self, bits: int) -> None:
        if bits != self.outputs:
            self.outputs = bits
            self.output_log.append((time.monotonic(), bits))
            del self.output_log[:-4096]

    def servo_reads(self) -> list[int]:
        """The register value the script read in every cycle so far."""
        return [read for _, read in self.cycles]

    # -- control interface ----------------------------------------------------------------
    def _write(self, value: int) -> None:
        with self._lock:
            self._writes.append(value)
            self._last_write = time.monotonic()

    def _wait_link(self) -> bool:
        """Block like a command that waits for the controller's answer; False on timeout."""
        return self._link.wait(self.block_s)

    def setWatchdog(self, min_frequency: float) -> bool:
        self.calls.append("setWatchdog")
        if not self._wait_link() or not self.running:
            return False
        self._write(CMD_SET_WATCHDOG)
        self.watchdog_hz = float(min_frequency)
        return True

    def kickWatchdog(self) -> bool:
        self.calls.append("kickWatchdog")
        self._write(CMD_NONE)
        return self.running

    def servoJ(
        self, q: list[float], v: float, a: float, t: float, lookahead: float, gain: float
    ) -> bool:
        self.calls.append("servoJ")
        if not self.running:
            return False
        self._write(CMD_SERVOJ)
        self.targets.append(np.array(q, dtype=float))
        with self._lock:
            self._pending = (np.array(q, dtype=float), (float(t), float(lookahead)))
        return True

    def servoStop(self, a: float = 10.0) -> bool:
        self.calls.append("servoStop")
        if not self._wait_link() or not self.running:
            return False
        self._write(CMD_SERVO_STOP)
        with self._lock:
            self._target = None
            self.qd[:] = 0.0
        return True

    def stopScript(self) -> None:
        """ur_rtde's stopScript: the control script stops (runstate outputs drop)."""
        self.calls.append("stopScript")
        self.stop_program()

    def sendCustomScriptFunction(self, name: str, script: str) -> bool:
        """Run a script function; only its runstate calls have an effect here."""
        self.calls.append("sendCustomScriptFunction")
        if not self._wait_link():
            return False
        with self._lock:
            for n, state in RUNSTATE_CALL.findall(script):
                self.runstate[int(n)] = int(state)
        return True

    def reuploadScript(self) -> bool:
        self.calls.append("reuploadScript")
        if not self._wait_link() or self.safety_mode not in (1, 2) or not self.remote_control:
            return False
        with self._lock:
            self.running = True
            self.watchdog_hz = 0.0
            self.reuploads += 1
            self._last_write = time.monotonic()
            self._idle_cycles = 0
        return True

    def initPeriod(self) -> datetime.timedelta:
        return datetime.timedelta(seconds=time.monotonic())

    def waitPeriod(self, t0: Any = None) -> None:
        """End of the driver's period: the controller runs one cycle."""
        self.cycle()
        if self.realtime:
            self._next = pace(self._next)

    def isConnected(self) -> bool:
        return self.connected

    def isProgramRunning(self) -> bool:
        return self.running

    def disconnect(self) -> None:
        self.calls.append("disconnect")
        self._wait_link()

    # -- receive interface ---------------------------------------------------------------
    def getActualQ(self) -> list[float]:
        q = self.q if self.link_alive else self._frozen[0]
        return list(map(float, q))

    def getActualQd(self) -> list[float]:
        qd = self.qd if self.link_alive else self._frozen[1]
        return list(map(float, qd))

    def getTimestamp(self) -> float:
        return self.timestamp if self.link_alive else self._frozen[2]

    def getSpeedScalingCombined(self) -> float:
        return self.speed_scaling

    def getSafetyMode(self) -> int:
        return self.safety_mode

    def getSafetyStatusBits(self) -> int:
        bit = {1: 0, 2: 1, 3: 2, 4: 3, 5: 4, 7: 6}.get(self.safety_mode, 10)
        return 1 << bit

    def isProtectiveStopped(self) -> bool:
        return self.safety_mode == 3

    def isEmergencyStopped(self) -> bool:
        return self.safety_mode in (6, 7)

    def getRobotMode(self) -> int:
        return 7  # running

    def getActualDigitalOutputBits(self) -> int:
        return self.outputs

    # -- io interface (rtde_io.RTDEIOInterface) ------------------------------------------
    def setStandardDigitalOut(self, output_id: int, signal_level: bool) -> bool:
        """Switch an output; the receive side sees it from the next controller cycle."""
        with self._lock:
            bit = 1 << int(output_id)
            self._outputs_pending = (self._outputs_pending & ~bit) | (bit if signal_level else 0)
        return True

    # -- one controller cycle ---------------------------------------------------------------
    def cycle(self) -> None:
        """Read the register (last write of the cycle), move the arm, check the watchdog."""
        with self._lock:
            writes, self._writes = self._writes, []
            self._idle_cycles = 0 if writes else self._idle_cycles + 1
            read = writes[-1] if writes else (self.cycles[-1][1] if self.cycles else CMD_NONE)
            self.cycles.append((writes, read))
            if not self.link_alive:
                return
            self.timestamp += CYCLE
            self._set_outputs(self._outputs_pending)
            if read == CMD_SERVOJ and writes and self.running:
                self._target, self._servo_args = self._pending
            self._move()
            wd = self.watchdog_hz
            gap = (
                time.monotonic() - self._last_write if self.realtime else self._idle_cycles * CYCLE
            )
            if self.running and wd > 0 and gap > 1.0 / wd:
                self.watchdog_trips += 1
                self._program_stopped()

    def _move(self) -> None:
        q_old = self.q.copy()
        if self._target is not None and self.running:
            if not self.lag:
                self.q = self._target.copy()
            else:
                t_ctrl = CYCLE * max(self.speed_scaling, 0.0)  # controller time this cycle
                k = 1.0 - np.exp(-t_ctrl / max(self._servo_args[1], 1e-6))
                self.q = self.q + k * (self._target - self.q)
        self.qd = (self.q - q_old) / CYCLE


class FakeDashboard:
    """ur_rtde's ``DashboardClient`` (port 29999) answers of a healthy e-Series controller."""

    def __init__(self, controller: FakeURController) -> None:
        self.controller = controller
        self.version = "URSoftware 5.11.6.1130617 (Jun 06 2023)"

    def connect(self, timeout_ms: int = 2000) -> None:
        pass

    def disconnect(self) -> None:
        pass

    def polyscopeVersion(self) -> str:
        return self.version

    def robotmode(self) -> str:
        return "Robotmode: RUNNING"

    def safetystatus(self) -> str:
        names = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 5: "SAFEGUARD_STOP",
                 7: "ROBOT_EMERGENCY_STOP"}  # fmt: skip
        return f"Safetystatus: {names.get(self.controller.safety_mode, 'FAULT')}"

    def isInRemoteControl(self) -> bool:
        return self.controller.remote_control


#: what a FakeURLink reads once per period (receive side) and caches until the next
SNAPSHOT = ("getActualQ", "getActualQd", "getTimestamp", "getSpeedScalingCombined",
            "getSafetyMode", "isProtectiveStopped", "isEmergencyStopped",
            "getActualDigitalOutputBits", "isProgramRunning", "isConnected")  # fmt: skip


def serve(controller: FakeURController, port: int = 0) -> tuple[int, threading.Event]:
    """Run ``controller`` behind a loopback TCP port (one JSON call per line, answer per
    line) and cycle it every 2 ms in a thread; the port and an event that stops both."""
    halt = threading.Event()
    srv = socket.create_server(("127.0.0.1", port))
    srv.settimeout(0.1)
    controller.realtime = True

    def clock() -> None:
        while not halt.is_set():
            controller.waitPeriod()

    def client(conn: socket.socket) -> None:
        f = conn.makefile("rwb")
        with conn, f, contextlib.suppress(OSError):  # the driver died: its socket with it
            for line in f:
                name, args = json.loads(line)
                if name == "snapshot":
                    out: Any = {k: getattr(controller, k)() for k in SNAPSHOT}
                else:
                    out = getattr(controller, name)(*args)
                f.write(json.dumps(out).encode() + b"\n")
                f.flush()

    def accept() -> None:
        with srv:
            while not halt.is_set():
                try:
                    conn, _ = srv.accept()
                except TimeoutError:
                    continue
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                threading.Thread(target=client, args=(conn,), daemon=True).start()

    for fn in (clock, accept):
        threading.Thread(target=fn, daemon=True).start()
    return int(srv.getsockname()[1]), halt


class FakeURLink:
    """RTDE control, receive and IO of a driver process on a controller run by :func:`serve`:
    one ``snapshot`` call per period (``initPeriod``) feeds the receive getters; commands are
    calls; ``waitPeriod`` paces the loop at 2 ms (the controller cycles by itself). A
    broken socket raises RuntimeError, as ur_rtde does."""

    def __init__(self, port: int) -> None:
        self._sock = socket.create_connection(("127.0.0.1", port), timeout=2.0)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._file = self._sock.makefile("rwb")
        self._lock = threading.Lock()
        self._snap: dict[str, Any] = self._call("snapshot")
        self._next = time.monotonic()

    def _call(self, name: str, *args: Any) -> Any:
        with self._lock:
            try:
                self._file.write(json.dumps([name, list(args)]).encode() + b"\n")
                self._file.flush()
                line = self._file.readline()
            except OSError as exc:
                raise RuntimeError(f"RTDE socket: {exc}") from exc
        if not line:
            raise RuntimeError("RTDE socket closed by the controller")
        return json.loads(line)

    def __getattr__(self, name: str) -> Any:
        if name in SNAPSHOT:
            return lambda: self._snap[name]
        if name.startswith("_"):
            raise AttributeError(name)
        return lambda *args: self._call(name, *args)

    def initPeriod(self) -> datetime.timedelta:
        self._snap = self._call("snapshot")
        return datetime.timedelta(seconds=time.monotonic())

    def waitPeriod(self, t0: Any = None) -> None:
        self._next = pace(self._next)

    def disconnect(self) -> None:
        with self._lock:
            self._sock.close()
