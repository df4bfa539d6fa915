"""The laser outputs of a robot driver and their emission supervisor.

:class:`LaserGate` is driven from the control loop of :class:`drivers.robot.node.RobotNode`
once per period. It switches two digital outputs of the arm: the treatment gate
(``laser.gate``) and the aiming (pilot) beam (``laser.aim``; with ``aim: gate`` the gate
output itself, a rig whose only laser is a low-power diagnostic diode).

- **Treatment** is wanted while the followed trajectory plays one of its ``laser_on``
  intervals (:meth:`drivers.robot.follower.TrajectoryFollower.laser_edge`) or while a
  followed setpoint stream's newest setpoint has ``laser_on``;
- **aim** while it plays one of its ``aim_on`` intervals or the newest setpoint has ``aim``.

Whatever it is sent, the supervisor (:class:`Emission`, the scenario's ``laser.limits``
and ``laser.power``) keeps treatment off, and asks the node to abort the motion, when:

1. the longest continuous on-time ``max_on`` (s) would be passed;
2. the energy of one continuous on-interval (one spot) would pass ``max_spot_energy`` (J);
3. the energy of this driver session has reached ``max_session_energy`` (J): latched until
   the driver restarts;
4. the speed fraction (slider, pause, reduced mode) is below 1 inside an interval: the
   planned exposure would stretch;
5. an arm of the beam chain is not live and following (the node's ``chain`` reason);
5a. the following error ``|q_measured - q_commanded|`` (commanded: the follower's command
   ``backend.following_lag`` s earlier, the controller's smoothing delay) maps through the
   beam Jacobian's gain (:func:`drivers.robot.following.spot_gain`) to a spot error above
   ``following_tolerance`` (m);
6. the outputs read back (:attr:`drivers.robot.backend.Measured.outputs`) differ from what
   was commanded, :data:`READBACK_GRACE` s after the last write: latched as a fault (every
   output off, every later interval refused) until :meth:`LaserGate.recover` finds them
   agreeing again.

Both outputs are off on a backend fault, and forced off (commanded again even if already
off) at start-up, in every safety stop and at exit. Each treatment switch is recorded as a
:class:`GateSwitch`; every change of either output is published as a
:class:`schemas.messages.LaserState` whose ``reason`` names the interval, limit or fault.
Times in s, energies in J.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from planner.bus.session import encode
from schemas import defaults
from schemas.messages import LaserState

MAX_SWITCHES = 4096  # switches remembered
EDGE_SLACK = 1e-6  # s
#: s after an output write in which its read-back may still show the old level (the UR
#: backend writes outputs from a helper thread; RTDE reports them a period or two later)
READBACK_GRACE = 0.030
#: speed fraction below which an interval counts as slowed (the slider's float noise)
SPEED_SLACK = 1e-3
#: periods of commanded joints kept for the following check (0.4 s at 500 Hz)
COMMAND_HISTORY = 200
#: s the gate output must stay dark before the on-time and spot-energy accumulators restart
#: (a dwell split into short intervals is one exposure)
COOL_DOWN = 0.5  # the planner's check (planner.service.emission) counts the same way


@dataclass(frozen=True)
class Emission:
    """What the gate's driver enforces: the gate output; the aim output (None without an
    aim beam, equal to ``gate_output`` for ``aim: gate``); ``power`` (W) and the limits of
    ``laser.limits`` (None: no limit)."""

    gate_output: int
    aim_output: int | None = None
    power: float | None = None
    max_on: float | None = None
    max_spot_energy: float | None = None
    max_session_energy: float | None = None
    following_gain: tuple[float, ...] | None = None  # m/rad per joint (None: not checked)
    following_tolerance: float = 1e-3  # m: largest spot error of the following error

    @classmethod
    def from_laser(cls, laser: Any, following_gain: Any = None,
                   following_tolerance: float = 1e-3) -> Emission:  # fmt: skip
        """The rules of a scenario's ``system.laser`` (its ``gate`` must be set), with the
        gate robot's following gain (m/rad per joint) when it is checked."""
        gate, aim, lim = laser.gate, laser.aim, laser.limits
        aim_output = None if aim is None else gate.output if aim == "gate" else aim.output
        gain = None if following_gain is None else tuple(float(g) for g in following_gain)
        return cls(gate.output, aim_output, laser.power, lim.max_on, lim.max_spot_energy,
                   lim.max_session_energy, gain, following_tolerance)  # fmt: skip

    def on_limit(self) -> tuple[float, str] | None:
        """The longest continuous on-time (s) the limits allow and the limit that sets it."""
        out: list[tuple[float, str]] = []
        if self.max_on is not None:
            out.append((self.max_on, f"max_on {self.max_on:g} s"))
        if self.max_spot_energy is not None and self.power:
            out.append((self.max_spot_energy / self.power,
                        f"max_spot_energy {self.max_spot_energy:g} J at {self.power:g} W"))  # fmt: skip
        return min(out) if out else None


class GateSwitch(NamedTuple):
    """One switch: ``on``; the interval edge it plays (s, reference time; None for a forced
    or fault switch), the reference time it was switched at, ``lag`` = their difference (s);
    ``latency`` (s) from the control period's start to the output command; ``reason``."""

    on: bool
    edge: float | None
    tau: float
    lag: float
    latency: float
    reason: str


class LaserGate:
    """The laser outputs of ``robot`` under ``rules``, commanded through
    ``backend.set_output`` and published with ``put`` (bytes)."""

    def __init__(self, robot: str, rules: Emission | int, backend: Any,
                 put: Callable[[bytes], Any], clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self.rules = rules if isinstance(rules, Emission) else Emission(int(rules))
        self.robot, self.backend, self._put, self.clock = robot, backend, put, clock
        self.output = self.rules.gate_output
        self.on = False  # treatment
        self.aim = False  # aiming beam
        self.switches: list[GateSwitch] = []
        self.period_start = clock()  # monotonic s, set by the loop every period
        self.on_time = 0.0  # s of the current continuous treatment interval
        self.total_on = 0.0  # s of treatment this session
        self.fault: str | None = None  # latched read-back fault
        self.spent: str | None = None  # latched session-energy limit
        self.reason: str | None = None  # why the outputs are as they are
        self._bits = 0  # commanded output levels (bit k = output k)
        self._written: dict[int, float] = {}  # output -> monotonic s of its last level change
        self._confirmed: dict[int, bool] = {}  # output -> its last level change was read back
        self.dark = 0.0  # s the gate output has been off
        self._commands: deque[tuple[float, Any]] = deque(maxlen=COMMAND_HISTORY)
        self._last: float | None = None  # monotonic s of the last update
        self.mismatches = 0

    # -- figures ----------------------------------------------------------------------------
    @property
    def session_energy(self) -> float | None:
        """J emitted by the treatment beam this session (None without ``laser.power``)."""
        return None if self.rules.power is None else self.rules.power * self.total_on

    # -- the period ---------------------------------------------------------------------------
    @property
    def _aim_is_gate(self) -> bool:
        """``aim: gate``: the aiming beam is the gate output itself (a diagnostic diode)."""
        return self.rules.aim_output == self.rules.gate_output

    def update(self, m: Any, fault: str | None, streamed: bool = False, aim: bool = False,
               chain: str | None = None, late: str | None = None) -> str | None:  # fmt: skip
        """This period's outputs from the follower, the newest setpoint's ``streamed``
        (laser_on) and ``aim``, the backend ``fault``, the node's ``chain`` reason (an arm of
        the beam chain not live) and ``late`` (why a streamed laser_on is not honoured: a
        late setpoint). Returns why the motion must be aborted, if so."""
        now = self.clock()
        self._charge(now)
        self._commands.append((now, np.array(self.backend.follower.q, dtype=float)))
        latched = self.fault
        self._check_readback(m, now)
        if self.fault is not None and latched is None:  # latched now: abort once
            self.force_off(self.fault)
            return self.fault
        follower = self.backend.follower
        healthy = fault is None and self.fault is None
        streaming = follower.mode == "streaming"
        edge = follower.laser_edge() if healthy else None
        treat = edge is not None or (healthy and streamed and streaming)
        aim_edge = follower.aim_edge() if healthy else None
        want_aim = (
            self.rules.aim_output is not None
            and healthy
            and (aim_edge is not None or (aim and streaming))
        )
        gate_wanted = treat or (want_aim and self._aim_is_gate)
        if gate_wanted:  # the gate output is held to every limit, lit for aim or not
            abort = self._blocked(m, chain)
            if abort is not None:
                self.force_off(abort)
                return abort
        gate_dark = not self.on and not (self.aim and self._aim_is_gate)
        if gate_wanted and gate_dark and not self._confirmed_off(self.rules.gate_output):
            treat = False  # on again only once the last off is read back
            want_aim = want_aim and not self._aim_is_gate
        if treat == self.on and want_aim == self.aim:
            return None
        if treat:
            why = "laser_on interval" if edge is not None else "setpoint laser_on"
        elif self.on:
            why = fault or (late or "setpoint laser off" if streaming else "interval ended")
        elif want_aim:
            why = "aim interval" if aim_edge is not None else "setpoint aim"
        else:
            why = fault or "aim ended"
        off_edge = self._off_edge(follower) if self.on and not treat and not streaming else None
        self._switch(treat, want_aim, edge if treat else off_edge, why)
        return None

    def _charge(self, now: float) -> None:
        """Charge the time since the last update to the gate output's on-time (treatment,
        and the aim too when it is the gate output): the whole elapsed time, so a stalled
        loop is charged what it emitted. The accumulators restart after :data:`COOL_DOWN` s
        dark, so splitting one dwell into short intervals does not reset them."""
        if self._last is not None:
            dt = max(now - self._last, 0.0)
            if self.on or (self.aim and self._aim_is_gate):
                self.on_time += dt
                self.total_on += dt
                self.dark = 0.0
            else:
                self.dark += dt
                if self.dark >= COOL_DOWN:
                    self.on_time = 0.0
        self._last = now

    def _blocked(self, m: Any, chain: str | None) -> str | None:
        """Why the gate output may not be on this period (rules 1-5 of the module docstring)."""
        r = self.rules
        if self.spent is not None:
            return self.spent
        energy = self.session_energy
        cap = r.max_session_energy
        period = 1.0 / max(float(getattr(self.backend, "rate", defaults.SERVO_RATE_HZ)), 1.0)
        if (cap is not None and energy is not None and r.power is not None
                and energy + r.power * period > cap * (1 + 1e-9)):  # fmt: skip
            self.spent = (f"max_session_energy {cap:g} J reached ({energy:.4g} J emitted): "
                          "restart the driver to treat again")  # fmt: skip
            return self.spent
        limit = r.on_limit()
        if limit is not None and self.on_time + period > limit[0] + EDGE_SLACK:
            return (f"{limit[1]} reached: treatment on {self.on_time:.3f} s "
                    f"(limit {limit[0]:.3f} s); motion aborted")  # fmt: skip
        speed = float(getattr(m, "speed", 1.0))
        if speed < 1.0 - SPEED_SLACK:
            return (f"speed fraction {100 * speed:.0f} % < 100 % inside a laser interval "
                    "(slider, pause or reduced mode): treatment off, motion aborted")  # fmt: skip
        if chain is not None:
            return f"beam chain not live: {chain}"
        return self._following(m)

    def _following(self, m: Any) -> str | None:
        """Rule 5a: the spot error of the following error, above the tolerance."""
        gain = self.rules.following_gain
        if gain is None or getattr(m, "q", None) is None or not self._commands:
            return None
        # the command the arm should have reached by now: ``following_lag`` s ago (the
        # controller's smoothing delay; 0 for the sim)
        lag = float(getattr(self.backend, "following_lag", 0.0))
        due = self.clock() - lag
        q_cmd = next((q for t, q in reversed(self._commands) if t <= due), self._commands[0][1])
        dq = np.abs(np.asarray(m.q, dtype=float) - np.asarray(q_cmd, dtype=float))
        err = float(np.asarray(gain) @ dq)
        if err <= self.rules.following_tolerance:
            return None
        j = int(np.argmax(np.asarray(gain) * dq))
        return (f"following error: the spot is off by up to {1e3 * err:.2f} mm (> "
                f"{1e3 * self.rules.following_tolerance:g} mm; joint {j} "
                f"{1e3 * dq[j]:.2f} mrad from its command): treatment off, motion aborted")  # fmt: skip

    def _mask(self) -> list[int]:
        outs = [self.rules.gate_output]
        if self.rules.aim_output is not None and self.rules.aim_output not in outs:
            outs.append(self.rules.aim_output)
        return outs

    def _mismatch(self, m: Any, now: float) -> str | None:
        """Rule 6 for the outputs read back in ``m``: each output must read its commanded
        level, except within :data:`READBACK_GRACE` s of its own last write (then either
        level), which also marks whether its last write is confirmed."""
        bits = getattr(m, "outputs", None)
        for k in self._mask():
            if bits is None:  # a backend that cannot read back: nothing to confirm
                self._confirmed[k] = True
                continue
            said, reads = bool(self._bits >> k & 1), bool(int(bits) >> k & 1)
            if said == reads:
                self._confirmed[k] = True
            elif now - self._written.get(k, -float("inf")) >= READBACK_GRACE:
                return (f"laser output {k} reads {'high' if reads else 'low'}, commanded "
                        f"{'high' if said else 'low'} (read-back mismatch): laser off, "
                        "motion aborted")  # fmt: skip
        return None

    def _check_readback(self, m: Any, now: float) -> None:
        """Latch a read-back mismatch as :attr:`fault`."""
        wrong = self._mismatch(m, now)
        if wrong is not None and self.fault is None:
            self.mismatches += 1
            self.fault = wrong

    def _confirmed_off(self, k: int) -> bool:
        """Whether output ``k``'s last write was read back (an output may switch on again
        only once its previous off is confirmed: a stuck-high output toggled faster than
        the grace would otherwise never be seen)."""
        return self._confirmed.get(k, True)

    def recover(self, m: Any) -> str:
        """Clear a read-back fault once the outputs read as commanded (all off)."""
        if self.fault is None:
            return "laser outputs: no fault"
        if self._mismatch(m, float("inf")) is not None:
            return f"laser outputs still faulted: {self.fault}"
        self.fault = None
        self.reason = "read-back fault cleared"
        self.publish(self.reason)
        return "laser outputs: read-back agrees again, fault cleared"

    # -- switching ----------------------------------------------------------------------------
    def force_off(self, reason: str) -> None:
        """Command both outputs off now, whatever their state."""
        self._switch(False, False, None, reason, force=True)

    def _levels(self, treat: bool, aim: bool) -> dict[int, bool]:
        r = self.rules
        out = {r.gate_output: treat}
        if r.aim_output is not None:
            out[r.aim_output] = out.get(r.aim_output, False) or aim
        return out

    def _switch(self, on: bool, aim: bool, edge: float | None, reason: str,
                force: bool = False) -> None:  # fmt: skip
        tau = self.backend.follower.tau
        for output, level in self._levels(on, aim).items():
            bit = 1 << output
            old = bool(self._bits & bit)
            self._bits = self._bits | bit if level else self._bits & ~bit
            if force or level != old:
                self.backend.set_output(output, level)
                if level != old:
                    self._written[output] = self.clock()
                    self._confirmed[output] = False
        latency = self.clock() - self.period_start
        changed = on != self.on or aim != self.aim
        if on != self.on:
            lag = tau - edge if edge is not None else 0.0
            self.switches.append(GateSwitch(on, edge, tau, lag, latency, reason))
            del self.switches[:-MAX_SWITCHES]
        self.on, self.aim = on, aim
        self.reason = reason
        if changed or force:
            self.publish(reason)

    @staticmethod
    def _off_edge(follower: Any) -> float | None:
        """The end (s, reference time) of the interval just left, if one was."""
        ref = follower.reference
        if follower.mode != "following" or ref is None or ref.laser_on is None:
            return None
        ends = ref.laser_on[:, 1] - ref.t[0]
        before = ends[ends <= follower.tau + EDGE_SLACK]
        return float(before[-1]) if len(before) else None

    def publish(self, reason: str | None = None) -> None:
        """The current state on ``<prefix>/laser`` (with the last switch's figures)."""
        last = self.switches[-1] if self.switches else None
        msg = LaserState(robot=self.robot, t=time.time(), on=self.on,
                         aim=None if self.rules.aim_output is None else self.aim,
                         output=self.output, reason=reason or self.reason,
                         lag=None if last is None else last.lag,
                         latency=None if last is None else last.latency)  # fmt: skip

        self._put(encode(msg))
