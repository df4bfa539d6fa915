"""Jerk-limited trajectory following with Ruckig, stepped once per control period.

:class:`TrajectoryFollower` is the motion generator of both robot backends (the simulated
arm *is* its output; the UR backend sends its output to ``servoJ``). Joints in rad, rad/s,
rad/s^2; time in s. It is pure: no threads, no clock, one :meth:`TrajectoryFollower.step`
per period ``dt``.

Modes (one of :data:`MODES`):

1. ``approach`` - Ruckig (position interface, online: re-evaluated every period) drives the
   current state (q, qd, qdd) onto the start state of a newly received trajectory. This is
   what makes *any* command smooth: a trajectory sent while the arm is moving, or one that
   starts a little away from it, is joined without a jump.
2. ``following`` - the validated reference is played exactly (sampled at the period,
   linear interpolation between its samples). It was checked against the position,
   velocity and acceleration limits on receipt (:mod:`drivers.robot.node`).
3. ``settle`` - after the last sample Ruckig brings the arm to rest on the final position.
   A trajectory *queued* with :meth:`TrajectoryFollower.enqueue` while another runs
   starts instead when the running one reaches its last sample (approach from there).
4. ``streaming`` - a setpoint stream (:meth:`TrajectoryFollower.stream`): Ruckig (position
   interface, online) drives the state toward the latest streamed target (q, qd, qdd)
   within the velocity, acceleration and jerk limits; the caller updates the
   target every period (:mod:`drivers.robot.streaming` moves it on along its velocity
   between setpoints). Once on the target the arm plays it exactly. A stream that ends with
   the arm at rest goes ``idle`` (:meth:`TrajectoryFollower.finish_stream`); one that ends
   moving brakes.
5. ``braking`` - watchdog or fault: Ruckig's velocity interface takes the velocity to zero
   at once with the *stop* deceleration ``stop_acceleration`` (default 40 rad/s^2) and jerk
   ``stop_jerk`` (default 4000 rad/s^3: full deceleration within 10 ms), like a UR
   protective stop (category 2) rather than a planned motion, whose limits (UR5e default
   5 rad/s^2) are for work near people, not for stopping. Time to rest from joint speed v:
   ``2 sqrt(v / j)`` for ``v <= a^2 / j``, else ``v / a + a / j``: at most 89 ms from the
   3.14 rad/s velocity limit, so the arm is still within 100 ms of a fault from any speed.
6. ``idle`` / ``stopped`` - at rest (``stopped``: after a brake, until the next command).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, RuckigError

from planner.model.system import Limits
from planner.model.transforms import Array
from schemas import defaults

MODES = ("idle", "approach", "following", "settle", "streaming", "braking", "stopped")
REST_VELOCITY = 1e-9  # rad/s: below this (every joint) the arm counts as at rest
STOP_ACCELERATION = 40.0  # rad/s^2, deceleration of a watchdog/fault stop
STOP_JERK = 4000.0  # rad/s^3


LASER_EDGE = 1e-6  # s: slack on a laser interval's ends (they lie on the period grid)
#: rad: Ruckig 0.19 raises on a rest-to-rest distance of exactly 2 a^3 / j^2 (the profile
#: that just touches the acceleration limit: 0.1 rad at 5 rad/s^2, 50 rad/s^3) for about
#: two in three starting positions, and plans a 250 s motion from the states along that
#: profile; a target this much further away is solved (kept while the target stands)
RUCKIG_NUDGE = 1e-10


def interval_start(spans: Array | None, t0: float, tau: float) -> float | None:
    """The start (s after ``t0``) of the interval of ``spans`` (m x 2, absolute s) that
    contains ``tau`` s after ``t0``, or None."""
    if spans is None or not len(spans):
        return None
    rel = spans - t0
    k = int(np.searchsorted(rel[:, 0], tau + LASER_EDGE, side="right")) - 1
    if k >= 0 and tau <= rel[k, 1] + LASER_EDGE:
        return float(rel[k, 0])
    return None


@dataclass(frozen=True)
class Reference:
    """A joint trajectory: ``q[k], qd[k], qdd[k]`` (K x n) at ``t[k]`` s from its start;
    ``laser_on`` (m x 2, s on the same axis, or None) the intervals in which the laser gate
    is on, ``aim_on`` those of the aiming beam."""

    t: Array
    q: Array
    qd: Array
    qdd: Array
    laser_on: Array | None = None
    aim_on: Array | None = None

    def laser_edge(self, tau: float) -> float | None:
        """The start (gate on) of the laser interval containing ``tau`` s after the first
        sample, or None when the gate is off then."""
        return interval_start(self.laser_on, self.t[0], tau)

    def aim_edge(self, tau: float) -> float | None:
        """Likewise for the aiming beam's intervals."""
        return interval_start(self.aim_on, self.t[0], tau)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def sample(self, tau: float) -> tuple[Array, Array, Array]:
        """State at ``tau`` s after the first sample (clamped to the ends; linear)."""
        t = self.t - self.t[0]
        k = int(np.clip(np.searchsorted(t, tau, side="right") - 1, 0, len(t) - 1))
        if k >= len(t) - 1:
            return self.q[-1], self.qd[-1], self.qdd[-1]
        s = (tau - t[k]) / (t[k + 1] - t[k])
        s = min(max(s, 0.0), 1.0)
        return tuple(  # type: ignore[return-value]
            a[k] + s * (a[k + 1] - a[k]) for a in (self.q, self.qd, self.qdd)
        )


class FollowerState(NamedTuple):
    """Output of one period: commanded joint state and the follower's mode."""

    q: Array
    qd: Array
    qdd: Array
    mode: str


class TrajectoryFollower:
    """Ruckig-based follower for one arm (see the module docstring for the modes)."""

    def __init__(
        self,
        q0: Array,
        limits: Limits,
        dt: float = 1.0 / defaults.SERVO_RATE_HZ,
        stop_acceleration: float = STOP_ACCELERATION,
        stop_jerk: float = STOP_JERK,
    ) -> None:
        self.n = len(q0)
        self.dt = dt
        self.limits = limits
        self._otg = Ruckig(self.n, dt)
        self._aim: tuple[Array, Array] | None = None  # (target, nudged target): RUCKIG_NUDGE
        self._inp = InputParameter(self.n)
        self._out = OutputParameter(self.n)
        self._stop_acceleration = np.full(self.n, float(stop_acceleration))
        self._stop_jerk = np.full(self.n, float(stop_jerk))
        self.reset(q0)

    def reset(self, q: Array, qd: Array | None = None) -> None:
        """Re-synchronise to a measured state (rest unless ``qd`` given) and go idle."""
        self.q = np.asarray(q, dtype=float).copy()
        self.qd = np.zeros(self.n) if qd is None else np.asarray(qd, dtype=float).copy()
        self.qdd = np.zeros(self.n)
        self.mode = "idle"
        self.reference: Reference | None = None
        self.queued: Reference | None = None
        self.target: tuple[Array, Array, Array] | None = None  # streamed (q, qd, qdd)
        self._tau = 0.0

    @property
    def state(self) -> FollowerState:
        return FollowerState(self.q.copy(), self.qd.copy(), self.qdd.copy(), self.mode)

    @property
    def tau(self) -> float:
        """Time (s) since the followed reference's first sample (0 outside ``following``)."""
        return self._tau if self.mode == "following" else 0.0

    def laser_edge(self) -> float | None:
        """While a reference is played: the start (s, reference time) of the laser interval
        the current sample lies in; None (gate off) in every other mode and outside them."""
        if self.mode != "following" or self.reference is None:
            return None
        return self.reference.laser_edge(self._tau)

    def aim_edge(self) -> float | None:
        """Likewise for the aiming beam's intervals."""
        if self.mode != "following" or self.reference is None:
            return None
        return self.reference.aim_edge(self._tau)

    def follow(self, reference: Reference) -> None:
        """Start a new trajectory (replaces any current one, a stream too): approach its
        start, then play."""
        self.reference = reference
        self.queued = None
        self.target = None
        self._tau = 0.0
        self.mode = "approach"

    def enqueue(self, reference: Reference) -> None:
        """Start ``reference`` when the running trajectory reaches its last sample (replaces
        a previously queued one); at once when nothing runs."""
        if self.mode in ("approach", "following", "settle"):
            self.queued = reference
        else:
            self.follow(reference)

    def stream(self, q: Array, qd: Array, qdd: Array | None = None) -> None:
        """Make (q, qd, qdd) (rad, rad/s, rad/s^2; qdd default 0) the state to reach from
        the next step on; replaces any trajectory. ``qd`` and ``qdd`` are clipped to the
        velocity and acceleration limits (Ruckig refuses a target beyond them); the caller
        checked them against the limits."""
        vmax = np.asarray(self.limits.velocity, dtype=float)
        amax = np.asarray(self.limits.acceleration, dtype=float)
        acc = np.zeros(self.n) if qdd is None else np.asarray(qdd, dtype=float)
        self.target = (
            np.asarray(q, dtype=float).copy(),
            np.clip(np.asarray(qd, dtype=float), -vmax, vmax),
            np.clip(acc, -amax, amax),
        )
        self.reference = None
        self.queued = None
        self._tau = 0.0
        self.mode = "streaming"

    def finish_stream(self) -> bool:
        """End a stream: ``idle`` when the arm is at rest (True), else brake (False)."""
        if self.mode != "streaming":
            return self.mode in ("idle", "stopped")
        self.target = None
        if np.all(np.abs(self.qd) <= REST_VELOCITY):
            self.qd[:] = 0.0
            self.qdd[:] = 0.0
            self.mode = "idle"
            return True
        self.brake()
        return False

    def brake(self) -> None:
        """Decelerate to rest now (no-op when already at rest or braking)."""
        if self.mode in ("braking", "stopped"):
            return
        self.reference = None
        self.queued = None
        self.target = None
        self.mode = "braking" if np.any(np.abs(self.qd) > REST_VELOCITY) else "stopped"
        if self.mode == "stopped":
            self.qd[:] = 0.0
            self.qdd[:] = 0.0

    def step(self) -> FollowerState:
        """Advance one period ``dt`` and return the new commanded state."""
        if self.mode == "approach":
            assert self.reference is not None
            q0, qd0, qdd0 = self.reference.sample(0.0)
            if self._ruckig(q0, qd0, qdd0):
                self.mode = "following"
                self._tau = 0.0
        elif self.mode == "following":
            assert self.reference is not None
            self._tau += self.dt
            self.q, self.qd, self.qdd = (np.array(a) for a in self.reference.sample(self._tau))
            if self._tau >= self.reference.duration:
                self.mode = "settle"
                if self.queued is not None:
                    self.follow(self.queued)
        elif self.mode == "settle":
            assert self.reference is not None
            if self.queued is not None:
                self.follow(self.queued)
                return self.step()
            if self._ruckig(self.reference.q[-1], np.zeros(self.n), np.zeros(self.n)):
                self.mode = "idle"
                self.reference = None
        elif self.mode == "streaming":
            assert self.target is not None
            self._ruckig(*self.target)
        elif self.mode == "braking" and self._ruckig_brake():
            self.mode = "stopped"
        return self.state

    def _load(self, jerk: Array, acceleration: Array | None = None) -> InputParameter:
        inp = self._inp
        inp.current_position = self.q.tolist()
        inp.current_velocity = self.qd.tolist()
        inp.current_acceleration = self.qdd.tolist()
        inp.max_velocity = np.asarray(self.limits.velocity, dtype=float).tolist()
        acc = self.limits.acceleration if acceleration is None else acceleration
        inp.max_acceleration = np.asarray(acc, dtype=float).tolist()
        inp.max_jerk = np.asarray(jerk, dtype=float).tolist()
        return inp

    def _take(self, result: Result) -> bool:
        if result not in (Result.Working, Result.Finished):
            raise RuntimeError(f"Ruckig failed with {result} from q={self.q}, qd={self.qd}")
        out = self._out
        self.q = np.array(out.new_position)
        self.qd = np.array(out.new_velocity)
        self.qdd = np.array(out.new_acceleration)
        return result == Result.Finished

    def _ruckig(self, q: Array, qd: Array, qdd: Array) -> bool:
        """One online Ruckig step toward state (q, qd, qdd); True once it is reached."""
        inp = self._load(self.limits.jerk)
        inp.control_interface = ControlInterface.Position
        q = np.asarray(q, dtype=float)
        aim = self._aim[1] if self._aim is not None and np.array_equal(q, self._aim[0]) else q
        inp.target_position = aim.tolist()
        inp.target_velocity = np.asarray(qd, dtype=float).tolist()
        inp.target_acceleration = np.asarray(qdd, dtype=float).tolist()
        try:
            result = self._otg.update(inp, self._out)
        except RuckigError:  # the boundary case of RUCKIG_NUDGE: aim a hair further for as
            # long as this target stands, on a fresh instance (the failed call left the
            # online one mid-calculation)
            self._aim = (q.copy(), q + RUCKIG_NUDGE * np.sign(q - self.q))
            inp.target_position = self._aim[1].tolist()
            self._otg = Ruckig(self.n, self._otg.delta_time)
            result = self._otg.update(inp, self._out)
        done = self._take(result)
        if done:  # land exactly on the target (Ruckig finishes within numerical noise)
            self.q, self.qd, self.qdd = (np.asarray(a, dtype=float).copy() for a in (q, qd, qdd))
        return done

    def _ruckig_brake(self) -> bool:
        inp = self._load(self._stop_jerk, self._stop_acceleration)
        inp.control_interface = ControlInterface.Velocity
        inp.target_velocity = [0.0] * self.n
        inp.target_acceleration = [0.0] * self.n
        done = self._take(self._otg.update(inp, self._out))
        if done:
            self.qd[:] = 0.0
            self.qdd[:] = 0.0
        return done
