"""Real UR arm through ur_rtde (backend ``ur``): ``servoJ`` at 500 Hz, states from RTDE.

One command per period. ur_rtde's control script reads *one* command register
(``input_int_register_0``) once per 2 ms controller cycle, and every RTDE command writes it:
``servoJ`` 11, ``servoStop`` 16, and ``kickWatchdog`` 0 ("no command"; the RTDE watchdog
watches that register). Sending ``servoJ`` and then ``kickWatchdog`` in the same period
would leave 0 in the register and the servo target unread. So each period writes the
register exactly once: ``servoJ`` while the arm is servoed (it feeds the watchdog too),
``servoStop`` when a servo session ends, ``kickWatchdog`` only in periods without either.

Per control period (``rate``, 500 Hz on e-Series):

1. ``initPeriod()``; read the arm (``getActualQ``/``getActualQd``, rad, rad/s), the RTDE
   timestamp (``getTimestamp``: the link is *stale* when it has not advanced for
   :data:`STALE_AFTER` s), the speed slider (``getSpeedScalingCombined``) and the safety
   mode (``getSafetyMode``: normal, reduced, protective/safeguard/emergency stop, ...).
2. Faults (stale or lost link, a safety mode other than normal/reduced, the control script
   not running, a call that never returned) latch: the servo session ends (``servoStop`` in a
   helper thread, skipped on a dead link, where the RTDE watchdog stops the arm), the follower
   re-synchronises and every trajectory is refused. Only the operator clears it:
   :meth:`URRobot.recover` (``beamrelay robot recover``) checks that the cause is gone,
   re-uploads the control script, re-arms the RTDE watchdog and re-synchronises.
3. Otherwise the Ruckig follower (:mod:`drivers.robot.follower`) advances one period. Its
   playback of a trajectory is time-scaled by the speed slider ``s``: the trajectory clock
   advances ``s x dt`` per period, so the controller, which executes each servo target ``s``
   times slower, is commanded the same path at the speed it can follow. Below
   :data:`SPEED_FLOOR` new trajectories are refused. While the follower moves, its position
   goes to ``servoJ(q, 0, 0, 1/rate, lookahead_time, gain)``; once it is at rest the final
   target is held (still ``servoJ``) until the measured joints are within
   :data:`ARRIVE_TOLERANCE` of it, then the servo session ends with ``servoStop``.
4. ``waitPeriod()``.

The RTDE watchdog (``setWatchdog(watchdog_hz)``: the controller stops the arm when the
command register is not written for ``1/watchdog_hz`` s) is armed in the first period.

Calls that wait for the controller's answer (``servoStop``, ``setWatchdog``, ``reuploadScript``,
``disconnect``) never run in the control loop: :class:`drivers.robot.ur_link.AsyncCall`.
Every check and watchdog of :mod:`drivers.robot.node` applies unchanged; a safety stop calls
:meth:`URRobot.brake` (a jerk-limited stop of the command through ``servoJ``).
The laser outputs (``gate_output``, the treatment gate, and ``aim_output``, the aiming beam)
are standard digital outputs of the controller, written through
``RTDEIOInterface.setStandardDigitalOut`` by :meth:`URRobot.set_output` (the node decides
when). The write runs in a helper thread (:class:`drivers.robot.ur_link.AsyncCall`), never
in the control loop; one that does not return within :data:`IO_TIMEOUT` is a fault. Every
period reads them back (``getActualDigitalOutputBits``, :attr:`Measured.outputs`) with the
speed fraction (:attr:`Measured.speed`). All laser outputs go off on entering a fault and at
exit.

**Off when the driver dies.** At start-up every laser output is configured, through
``sendCustomScriptFunction``, with the URScript call
``set_runstate_standard_digital_output_to_value(n, 1)`` ("set signal to False when program is
not running"): the controller itself drops the output when the control script stops. With
the RTDE watchdog (the script stops when not kicked for ``1/watchdog_hz`` s) a SIGKILLed or
hung driver turns the laser off within ``1/watchdog_hz`` s plus a cycle. An RTDE socket error
(ur_rtde raises RuntimeError) is a fault; nothing reconnects inside the loop (the operator's
recover does, in a helper thread). How to run it on a real arm: ``drivers/README.md``.
"""
# long module: one ur_rtde backend: connection, servo session, faults, recovery, safety modes and the RTDE watchdog share its link

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from drivers.robot.backend import Measured
from drivers.robot.follower import STOP_ACCELERATION, Reference, TrajectoryFollower
from drivers.robot.ur_fake import FakeURLink
from drivers.robot.ur_link import MOTION_ALLOWED, AsyncCall, RateLimitedLog, safety_name
from planner.errors import InputError
from planner.model.system import Limits
from schemas import defaults

LOOKAHEAD_RANGE = (0.03, 0.2)  # s, accepted by servoJ
GAIN_RANGE = (100.0, 2000.0)  # servoJ proportional gain
MOVING = ("approach", "following", "settle", "streaming", "braking")
STALE_AFTER = 0.100  # s without a new RTDE timestamp: the link is stale
SPEED_FLOOR = 0.05  # speed slider below which new trajectories are refused
ARRIVE_TOLERANCE = 1e-4  # rad: the held final target counts as reached (every joint)
HOLD_STALL = 1.0  # s (at 100 % speed) without progress toward the held target: give up
CALL_TIMEOUT = 1.0  # s: longest wait for servoStop / disconnect
IO_TIMEOUT = 0.050  # s: longest wait for setStandardDigitalOut (a longer one is a fault)
RUNSTATE_TIMEOUT = 10.0  # s: sendCustomScriptFunction at start-up (re-uploads the script)
RUNSTATE_LOW_WHEN_STOPPED = 1  # URScript runstate: "False when program is not running"
RECOVER_TIMEOUT = 15.0  # s: reuploadScript + setWatchdog
RT_PRIORITY = 80  # SCHED_FIFO priority of ur_rtde's receive/control threads (--realtime)
LOOP_PRIORITY = 70  # SCHED_FIFO priority of the control loop (below ur_rtde's, as it advises)


class URRobot:
    """A UR arm behind RTDE, for :class:`drivers.robot.node.RobotNode`.

    ``control``/``receive`` default to ``rtde_control.RTDEControlInterface(host, rate)`` and
    ``rtde_receive.RTDEReceiveInterface(host, rate)`` (with ``rt_priority``); tests pass
    objects with the same methods (:class:`drivers.robot.ur_fake.FakeURController`).
    """

    kind = "ur"

    # long: the UR backend's 16 settings and its three RTDE interfaces are stored in one place; the body only assigns
    def __init__(
        self,
        host: str,
        names: tuple[str, ...],
        limits: Limits,
        *,
        robot: str = "",
        rate: float = defaults.SERVO_RATE_HZ,
        lookahead_time: float = defaults.SERVOJ_LOOKAHEAD_S,
        gain: float = defaults.SERVOJ_GAIN,
        watchdog_hz: float = 10.0,
        stop_acceleration: float = STOP_ACCELERATION,
        realtime: bool = False,
        control: Any = None,
        receive: Any = None,
        gate_output: int | None = None,
        aim_output: int | None = None,
        io: Any = None,
    ) -> None:
        if not LOOKAHEAD_RANGE[0] <= lookahead_time <= LOOKAHEAD_RANGE[1]:
            raise InputError(
                f"must be in {list(LOOKAHEAD_RANGE)} s, got {lookahead_time}", "--lookahead"
            )
        if not GAIN_RANGE[0] <= gain <= GAIN_RANGE[1]:
            raise InputError(f"must be in {list(GAIN_RANGE)}, got {gain}", "--gain")
        self.names = tuple(names)
        self.robot = robot
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        self.lookahead_time = lookahead_time
        # the arm reaches a servoJ command about one lookahead later: the emission
        # supervisor's following check compares the measured joints with that command
        self.following_lag = lookahead_time
        self.gain = gain
        self.watchdog_hz = watchdog_hz
        self.realtime = realtime
        if control is None or receive is None:
            control, receive = _connect(host, self.rate, RT_PRIORITY if realtime else 0)
        self.control = control
        self.receive = receive
        self.gate_output = gate_output
        #: every laser output (treatment gate, aim): off on fault, at close, at program stop
        self.laser_outputs = tuple(sorted({o for o in (gate_output, aim_output) if o is not None}))
        if self.laser_outputs and io is None:
            io = _connect_io(host)
        self.io = io
        self.io_call = AsyncCall()  # setStandardDigitalOut, out of the control loop
        self._io_want: dict[int, bool] = {}  # output -> level still to write
        self._outputs: int | None = None
        self.gate_calls: list[tuple[float, int, bool]] = []  # (monotonic s, output, state)
        q0 = np.asarray(self.receive.getActualQ(), dtype=float)
        self.follower = TrajectoryFollower(q0, limits, self.dt, stop_acceleration)
        self.log = RateLimitedLog(f"{robot or 'ur'}")
        self.call = AsyncCall()
        self.servoing = False  # a servo session is open on the controller
        self.holding = False  # holding the final target until the arm arrives
        self.fault: str | None = None  # latched until the operator recovers
        self.note: str | None = None  # outcome of the last recover / hold, for the status
        self.speed = 1.0
        self.safety = "normal"
        self.stale = False
        self.protective_stop = False
        self._ts = float(self.receive.getTimestamp())
        self._ts_at = time.monotonic()
        self._hold = (np.inf, 0.0)  # (best distance to the held target, when), rad, s
        self._t0: Any = None
        self._armed = False  # the RTDE watchdog is armed in the first period, not before:
        # the node may take seconds to start its loop, and nothing would feed it meanwhile
        self._last = Measured(q0.copy(), np.zeros(len(self.names)), "idle")
        self.runstate = self._configure_runstate()

    def _configure_runstate(self) -> dict[int, int]:
        """Every laser output set to go low when the control script stops (URScript
        ``set_runstate_standard_digital_output_to_value(n, 1)``); InputError when the
        controller does not confirm within RUNSTATE_TIMEOUT. What was configured."""
        if not self.laser_outputs:
            return {}
        script = "".join(
            f"  set_runstate_standard_digital_output_to_value({n}, {RUNSTATE_LOW_WHEN_STOPPED})\n"
            for n in self.laser_outputs
        )
        call = AsyncCall()
        call.start("runstate", lambda: self.control.sendCustomScriptFunction(
            "beamrelay_laser_runstate", script), RUNSTATE_TIMEOUT)  # fmt: skip
        done = call.wait(RUNSTATE_TIMEOUT + 0.1)
        if done is None or not done[1]:
            why = "no answer" if done is None else done[2]
            raise InputError(
                f"cannot set outputs {list(self.laser_outputs)} to go low at program stop "
                f"(set_runstate_standard_digital_output_to_value): {why}",
                "laser.gate",
            )
        return {n: RUNSTATE_LOW_WHEN_STOPPED for n in self.laser_outputs}

    # -- period ---------------------------------------------------------------------------
    def begin_period(self) -> None:
        if self.realtime:  # first period, in the control thread: ask for SCHED_FIFO once
            self.realtime = False
            self.log(set_realtime(LOOP_PRIORITY))
        self._t0 = self.control.initPeriod()

    def step(self) -> Measured:
        if not self._armed:
            self._armed = True
            self._ts_at = time.monotonic()  # staleness counts from the first period
            self.call.start("setWatchdog", lambda: self.control.setWatchdog(self.watchdog_hz),
                            CALL_TIMEOUT)  # fmt: skip
        try:
            q = np.asarray(self.receive.getActualQ(), dtype=float)
            qd = np.asarray(self.receive.getActualQd(), dtype=float)
            self._read_state()
        except RuntimeError as exc:  # a socket error: a fault, no reconnect in the loop
            return self._link_error(exc)
        self._finish_call(q)
        self._io_step(q)
        blocking = self._blocking_condition()
        if blocking is None and not self.control.isProgramRunning() and not self.call.busy:
            blocking = (
                "RTDE control script not running (watchdog tripped or stopped on the pendant)"
            )
        if blocking is not None:
            self._enter_fault(blocking, q)
        wrote = False
        try:
            if self.fault is None and not self.call.busy:
                wrote = self._servo(q)
            if not wrote and self._may_kick():
                self.control.kickWatchdog()
        except RuntimeError as exc:
            return self._link_error(exc)
        mode = "fault" if self.fault else ("settle" if self.holding else self.follower.mode)
        self._last = Measured(q, qd, mode, self.protective_stop, self.status_text(), self.stale,
                              self.safety, self.speed, self._outputs)  # fmt: skip
        return self._last

    def _link_error(self, exc: Exception) -> Measured:
        """An RTDE call raised (socket error): latch a fault, keep the last state, no
        reconnect here (the operator's recover runs in a helper thread)."""
        self.stale = True
        q = self._last.q
        self._enter_fault(f"RTDE link error: {exc}", q)
        self._last = Measured(q, np.zeros(len(self.names)), "fault", self.protective_stop,
                              self.status_text(), True, self.safety, self.speed, None)  # fmt: skip
        return self._last

    def _io_step(self, q: np.ndarray) -> None:
        """Collect the last output write; start the next one (outside the loop)."""
        done = self.io_call.poll()
        if done is not None and not done[1]:
            hung = self.io_call.stuck
            self._enter_fault(f"setStandardDigitalOut did not return within "
                              f"{1e3 * IO_TIMEOUT:.0f} ms" if hung
                              else f"setStandardDigitalOut failed: {done[2]}", q)  # fmt: skip
        if self._io_want and not self.io_call.busy and not self.io_call.stuck:
            want, self._io_want = dict(self._io_want), {}
            io = self.io

            def write() -> bool:
                return all(io.setStandardDigitalOut(n, on) is not False for n, on in want.items())

            self.io_call.start("setStandardDigitalOut", write, IO_TIMEOUT)

    def end_period(self) -> None:
        self.control.waitPeriod(self._t0)

    def _read_state(self) -> None:
        now, ts = time.monotonic(), float(self.receive.getTimestamp())
        if ts != self._ts:
            self._ts, self._ts_at = ts, now
        self.stale = now - self._ts_at > STALE_AFTER
        self.speed = float(np.clip(self.receive.getSpeedScalingCombined(), 0.0, 1.0))
        mode = int(self.receive.getSafetyMode())
        self.safety = safety_name(mode)
        self.protective_stop = bool(self.receive.isProtectiveStopped()) or mode == 3
        self._safety_mode = mode
        bits = self.receive.getActualDigitalOutputBits()
        self._outputs = None if bits is None or self.stale else int(bits) & 0xFF

    def _blocking_condition(self) -> str | None:
        """What stops motion now and must be gone before a recover (None: nothing)."""
        if self.stale:
            return (
                f"RTDE link stale: controller timestamp {self._ts:.3f} s unchanged for "
                f"{1e3 * (time.monotonic() - self._ts_at):.0f} ms"
            )
        if not (self.control.isConnected() and self.receive.isConnected()):
            return "RTDE connection lost"
        if self._safety_mode not in MOTION_ALLOWED or self.receive.isEmergencyStopped():
            return self.safety if self._safety_mode not in MOTION_ALLOWED else "emergency stop"
        if self.protective_stop:
            return "protective stop"
        if self.call.stuck:
            return "an RTDE call did not return: controller link hung"
        if self.io_call.stuck:
            return f"setStandardDigitalOut did not return within {1e3 * IO_TIMEOUT:.0f} ms"
        return None

    def _enter_fault(self, reason: str, q: np.ndarray) -> None:
        """Latch the first cause (later causes show as "now: ..." in the status); every
        laser output goes off first, on every fault."""
        self.log(f"fault: {reason}", key=reason.split(":")[0])  # once per cause every 5 s
        if self.fault is not None:
            return
        self.lasers_off()
        self._io_step(q)  # the off write starts now, before servoStop
        self.follower.reset(q)
        self.holding = False
        if self.servoing and not self.stale and self.control.isConnected():
            self.call.start("servoStop", self.control.servoStop, CALL_TIMEOUT)
        self.servoing = False
        self.fault = reason
        self.note = None

    def _may_kick(self) -> bool:
        return (
            not self.stale
            and not self.call.busy
            and not self.call.stuck
            and self.control.isConnected()
            and self.control.isProgramRunning()
        )

    # -- servo -----------------------------------------------------------------------------
    def _servo(self, q: np.ndarray) -> bool:
        """Advance the follower, write the period's one command; whether one was written."""
        f = self.follower
        f.dt = self.dt * self.speed  # trajectory clock: s x dt per period (speed slider)
        cmd = f.step()
        if cmd.mode in MOVING:
            self.holding = False
            self._hold = (np.inf, time.monotonic())
            return self._servo_j(cmd.q, q)
        if not self.servoing:
            return False
        err = float(np.max(np.abs(q - cmd.q)))
        best, since = self._hold
        now = time.monotonic()
        if err < 0.99 * best:
            self._hold = (err, now)
        elif now - since > HOLD_STALL / max(self.speed, SPEED_FLOOR):
            self.note = f"final target not reached: {1e3 * err:.2f} mrad off, servo stopped"
            self.log(self.note)
            err = 0.0
        if err <= ARRIVE_TOLERANCE:
            self.holding = self.servoing = False
            return self.call.start("servoStop", self.control.servoStop, CALL_TIMEOUT)
        self.holding = True
        return self._servo_j(cmd.q, q)

    def _servo_j(self, target: np.ndarray, q: np.ndarray) -> bool:
        ok = self.control.servoJ(target.tolist(), 0.0, 0.0, self.dt, self.lookahead_time, self.gain)
        self.servoing = True
        if ok is False:
            self._enter_fault("servoJ refused the command", q)
        return True

    # -- commands (called by the node's control loop, between periods) -----------------------
    def measured(self) -> Measured:
        return self._last

    def status_text(self) -> str | None:
        """The fault (or note) for the status: what happened and what the operator does."""
        if self.fault is None:
            return self.note
        text = self.fault
        now = self._blocking_condition()
        if now is not None and now != self.fault:
            text += f"; now: {now}"
        if self.call.name == "recover":
            text += "; recovering (re-uploading the control script)"
        elif now is None:
            who = f" --name {self.robot}" if self.robot else ""
            text += f"; cause cleared: run `beamrelay robot recover{who}` to resume"
        return text if self.note is None else f"{text}; {self.note}"

    def _ready(self) -> None:
        if self.fault is not None:
            raise InputError(f"arm in fault: {self.status_text()}", "robot")
        if self.speed < SPEED_FLOOR:
            raise InputError(
                f"speed slider at {100 * self.speed:.0f} % (< {100 * SPEED_FLOOR:.0f} %): "
                "raise it on the teach pendant",
                "robot",
            )

    def command(self, reference: Reference) -> None:
        self._ready()
        if not self.servoing:  # start from where the arm really is
            self.follower.reset(self._last.q)
        self.note = None
        self.follower.follow(reference)

    def queue(self, reference: Reference) -> None:
        """Start ``reference`` when the running trajectory reaches its last sample."""
        self._ready()
        self.follower.enqueue(reference)

    def start_stream(self) -> None:
        """A setpoint stream starts: refused in a fault or below the speed floor; from
        rest, the follower starts from where the arm really is."""
        self._ready()
        if not self.servoing:
            self.follower.reset(self._last.q)
        self.note = None

    def stream(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
        """This period's streamed target (sent through servoJ by the next step)."""
        self.follower.stream(q, qd, qdd)

    def brake(self, reason: str) -> None:
        """Decelerate the command at the stop deceleration (jerk-limited, through servoJ);
        the arm, which may lag its command, is held on the stop point, then servoStop."""
        self.holding = False
        self.follower.brake()

    def lasers_off(self) -> None:
        """Every laser output (gate and aim) off."""
        for n in self.laser_outputs:
            self.set_output(n, False)

    def set_gate(self, on: bool) -> None:
        """The laser gate: standard digital output ``gate_output`` through RTDE IO (no-op
        without one)."""
        if self.gate_output is not None:
            self.set_output(self.gate_output, on)

    def set_output(self, output: int, on: bool) -> None:
        """A standard digital output through RTDE IO (no-op without an IO link): queued, and
        written by the next period from a helper thread (IO_TIMEOUT). Every command is
        recorded with its monotonic time."""
        if self.io is None:
            return
        self._io_want[int(output)] = bool(on)
        self.gate_calls.append((time.monotonic(), output, bool(on)))
        del self.gate_calls[:-4096]

    def recover(self) -> str:
        """The operator's acknowledgement: re-upload the control script, re-arm the RTDE
        watchdog and re-synchronise, if the cause of the fault is gone. The outcome shows in
        :meth:`status_text`; the text returned says what happened now."""
        if self.fault is None:
            self.note = "recover: not in fault, nothing to do"
            return self.note
        blocking = self._blocking_condition()
        if blocking is not None or self.call.busy:
            self.note = f"recover refused: {blocking or 'an RTDE call is still running'}"
            return self.note

        def reupload_and_arm() -> bool:
            return bool(self.control.reuploadScript()) and bool(
                self.control.setWatchdog(self.watchdog_hz)
            )

        self.call.start("recover", reupload_and_arm, RECOVER_TIMEOUT)
        self.note = None
        return "recovering"

    def _finish_call(self, q: np.ndarray) -> None:
        done = self.call.poll()
        if done is None:
            return
        name, ok, detail = done
        if name == "recover":
            if ok and self._blocking_condition() is None:
                self.fault = None
                self.follower.reset(q)
                self.note = "recovered by the operator"
                self.log("recovered: control script re-uploaded, watchdog re-armed")
            else:
                self.note = f"recover failed: {detail or 'the cause came back'}"
                self.log(self.note)
        elif name == "setWatchdog" and not ok:
            self._enter_fault(f"the controller refused setWatchdog: {detail}", q)
        elif not ok:
            self.log(f"{name} failed: {detail}")

    def close(self) -> None:
        """Ctrl-C / exit: laser off, stop servoing and disconnect, each waiting at most
        CALL_TIMEOUT."""
        self.lasers_off()
        self._io_step(self._last.q)
        self.io_call.wait(CALL_TIMEOUT)
        self.call.wait(CALL_TIMEOUT)
        if self.servoing and self.call.start("servoStop", self.control.servoStop, CALL_TIMEOUT):
            self.call.wait(CALL_TIMEOUT + 0.1)
        self.servoing = False
        for iface in (self.control, self.receive):
            if self.call.start("disconnect", iface.disconnect, CALL_TIMEOUT):
                self.call.wait(CALL_TIMEOUT + 0.1)


def _connect(host: str, rate: float, rt_priority: int = 0) -> tuple[Any, Any]:
    """Open the RTDE control and receive interfaces (InputError when the arm is unreachable)."""
    from rtde_control import RTDEControlInterface
    from rtde_receive import RTDEReceiveInterface

    if host.startswith(FAKE_SCHEME):  # the simulated controller of another process (tests)
        link = _fake_link(host)
        return link, link
    try:
        receive = RTDEReceiveInterface(host, rate, [], False, False, rt_priority)
        control = RTDEControlInterface(
            host, rate, RTDEControlInterface.FLAG_UPLOAD_SCRIPT, 50002, rt_priority
        )
    except RuntimeError as exc:  # ur_rtde raises RuntimeError on connection failures
        raise InputError(f"cannot connect to the UR controller: {exc}", f"--host {host}") from exc
    return control, receive


def _connect_io(host: str) -> Any:
    """The RTDE IO interface that drives the laser gate output (InputError when unreachable)."""
    if host.startswith(FAKE_SCHEME):
        return _fake_link(host)
    from rtde_io import RTDEIOInterface

    try:
        return RTDEIOInterface(host)
    except RuntimeError as exc:
        raise InputError(
            f"cannot open RTDE IO on the UR controller: {exc}", f"--host {host}"
        ) from exc


FAKE_SCHEME = "ur-fake:"  # --host ur-fake:<port>: drivers.robot.ur_fake.serve on loopback


def _fake_link(host: str) -> Any:

    try:
        return FakeURLink(int(host[len(FAKE_SCHEME) :]))
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot reach the simulated controller: {exc}", f"--host {host}") from exc


def set_realtime(priority: int) -> str:
    """Put the calling thread under SCHED_FIFO at ``priority``; what happened (one line)."""

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError, AttributeError) as exc:
        return (
            f"--realtime: SCHED_FIFO not permitted ({exc}); grant CAP_SYS_NICE or an rtprio "
            "limit (/etc/security/limits.d), running with normal priority"
        )
    return f"--realtime: control loop under SCHED_FIFO priority {priority}"
