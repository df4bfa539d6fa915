"""Streaming joint setpoints to the robot drivers (``<prefix>/<robot>/setpoint``).

A :class:`SetpointStreamer` (one per request) publishes one
:class:`~schemas.messages.Setpoint` per robot every ``1 / rate`` s (default
:data:`schemas.defaults.SERVO_RATE_HZ`, 500 Hz) from its own thread, with the planner node's
heartbeat session id (the drivers follow a stream only while that session's heartbeat is
fresh), the request ``id`` and a ``seq`` that counts up. What it publishes comes from either

- ``reference(t) -> ({robot: (q, qd)}, laser_on)``, called once per period with ``t`` the
  UNIX time (s) the setpoint is stamped with; or
- :meth:`SetpointStreamer.update` calls: the state ``(q, qd)`` per robot at time ``t``,
  published moved on along ``qd`` to each period's time (``q + qd (now - t)``). A moving
  update older than ``max_hold`` s is not published (the drivers then stop the arms after
  50 ms); a state at rest (``qd = 0``) is held until the next update or :meth:`close`.

``laser_on`` goes to the robot that switches the laser (``gate_robot``) only, and with
``aim`` (the scenario has ``laser.aim``) so does ``aim`` while the treatment is off (the
aiming beam shows where the beam is while a tracked target is acquired); the others get
``false``. Joints in rad and rad/s, times in s.

The streaming thread asks for ``SCHED_FIFO`` (:func:`planner.bus.priority.raise_priority`,
nice as the fallback) like the other threads whose timing keeps the arm safe: a driver
switches treatment off at the first late setpoint and stops the arm 50 ms into a silent
stream, and a loaded machine's normal scheduler may leave the thread waiting that long. It
sleeps every period (its work per period is one reference call and the bodies).

What the drivers check (docs/conventions.md, "Setpoint streams"): the first setpoint within
0.01 rad and 0.1 rad/s of the arm's state; consecutive setpoints within the velocity limit
(``|q_k - q_k-1| / (t_k - t_k-1)``, so a position step of more than ``v_max / rate``,
6.3 mrad at 500 Hz and pi rad/s, is refused) and the acceleration limit (the same for
``qd``). A refused setpoint ends the stream: the arm brakes and the setpoints that follow
are ignored until the stream pauses for 50 ms (or a new request id starts another).

If ``reference`` raises or returns something that cannot be sent (a robot missing, NaN),
the streamer stops publishing and keeps the reason in :attr:`SetpointStreamer.error`; the
drivers' staleness stop brings the arms to rest. :meth:`SetpointStreamer.close` stops
publishing the same way (keep streaming the final setpoint until the arm is on it: the
drivers brake an arm that is still moving when the stream goes stale).
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from planner.bus.session import JSON, Keys
from planner.errors import InputError
from planner.model.transforms import Array
from schemas import defaults
from schemas.messages import SETPOINT_SCHEMA

log = logging.getLogger("beamrelay.setpoints")

#: ``{robot: (q, qd)}`` (rad, rad/s) and the laser gate state
States = tuple[Mapping[str, tuple[Any, Any]], bool]
Reference = Callable[[float], States]
MAX_HOLD = 0.1  # s: longest a moving update is moved on before publishing pauses
MAX_BEHIND = 5  # periods: a thread later than this skips them instead of catching up


class _Update(NamedTuple):
    t: float
    q: dict[str, Array]
    qd: dict[str, Array]
    laser_on: bool


class SetpointStreamer:
    """Publishes setpoints for ``robots`` on ``session`` (see the module docstring).

    ``session`` needs ``declare_publisher(key, encoding=...)`` (a Zenoh session); ``session_id`` is the node's heartbeat session
    (``PlannerNode.session_id``). ``clock`` gives the UNIX time (s) setpoints are stamped with.
    Use as ``start()`` ... ``close()`` or as a context manager.
    """

    def __init__(
        self,
        session: Any,
        keys: Keys,
        session_id: str,
        robots: Sequence[str],
        *,
        reference: Reference | None = None,
        rate: float = defaults.SERVO_RATE_HZ,
        request_id: str | None = None,
        gate_robot: str | None = None,
        aim: bool = False,
        max_hold: float = MAX_HOLD,
        clock: Callable[[], float] = time.time,
    ) -> None:
        if not math.isfinite(rate) or rate <= 0:
            raise InputError(f"must be a positive rate in Hz, got {rate}", "rate")
        if gate_robot is not None and gate_robot not in robots:
            raise InputError(f"{gate_robot!r} is not one of {list(robots)}", "gate_robot")
        self.robots = tuple(robots)
        self.session_id, self.request_id, self.gate_robot = session_id, request_id, gate_robot
        self.aim = aim and gate_robot is not None  # the aiming beam lit while treatment is off
        self.reference, self.rate, self.max_hold, self.clock = reference, rate, max_hold, clock
        self._pubs = {r: session.declare_publisher(keys.setpoint(r), encoding=JSON) for r in robots}
        self._lock = threading.Lock()
        self._update: _Update | None = None
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="setpoint-streamer", daemon=True)
        self.priority: Any = None  # the streaming thread's (planner.bus.priority.Priority)
        self.seq = 0  # setpoints sent so far per robot (the next seq)
        self.error: str | None = None
        self.late_max = 0.0  # s: the largest lateness of a period behind its schedule

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> SetpointStreamer:
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop publishing (the drivers stop the arms 50 ms later) and undeclare."""
        self._halt.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        pubs, self._pubs = self._pubs, {}
        for p in pubs.values():
            p.undeclare()

    def __enter__(self) -> SetpointStreamer:
        return self.start()

    def __exit__(self, *_: object) -> None:
        self.close()

    @property
    def running(self) -> bool:
        return self._thread.is_alive() and not self._halt.is_set()

    # -- input -------------------------------------------------------------------------------
    def update(
        self,
        q_by_robot: Mapping[str, Any],
        qd_by_robot: Mapping[str, Any] | None = None,
        laser_on: bool = False,
        t: float | None = None,
    ) -> None:
        """The state to stream from now on: ``q`` (rad) and ``qd`` (rad/s, default zero)
        per robot, every robot of the stream, at UNIX time ``t`` (default now). InputError
        naming the robot when one is missing or holds a non-finite value."""
        if self.reference is not None:
            raise InputError("this streamer follows its reference(t); update() is not used", "")
        if laser_on and self.gate_robot is None:
            raise InputError(
                "laser_on needs the robot that gates the laser (gate_robot)", "laser_on"
            )
        q, qd = {}, {}
        for r in self.robots:
            if r not in q_by_robot:
                raise InputError(f"no joint positions for robot {r!r}", "q")
            q[r] = _finite(q_by_robot[r], f"q[{r}]")
            raw = None if qd_by_robot is None else qd_by_robot.get(r)
            qd[r] = np.zeros_like(q[r]) if raw is None else _finite(raw, f"qd[{r}]")
            if qd[r].shape != q[r].shape:
                raise InputError(f"{qd[r].size} velocities for {q[r].size} joints", f"qd[{r}]")
        with self._lock:
            self._update = _Update(self.clock() if t is None else float(t), q, qd, bool(laser_on))

    # -- thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        from planner.bus.priority import raise_priority

        self.priority = raise_priority(reset_on_fork=True)
        period = 1.0 / self.rate
        due = time.monotonic()
        while not self._halt.is_set():
            try:
                self._publish(self.clock())
            except Exception as exc:  # the reference's or the caller's error: stop publishing
                self.error = f"{type(exc).__name__}: {exc}"
                log.error("setpoint stream %s stopped: %s", self.request_id, self.error)
                return
            due += period
            late = time.monotonic() - due
            self.late_max = max(self.late_max, late)
            if late > MAX_BEHIND * period:
                due = time.monotonic()  # hopelessly behind: skip, never burst
            self._halt.wait(max(0.0, -late))

    def _states(self, t: float) -> States | None:
        if self.reference is not None:
            return self.reference(t)
        with self._lock:
            u = self._update
        if u is None:
            return None
        age = max(0.0, t - u.t)
        moving = any(np.any(v != 0) for v in u.qd.values())
        if moving and age > self.max_hold:
            return None
        return {r: (u.q[r] + u.qd[r] * age, u.qd[r]) for r in self.robots}, u.laser_on

    def _publish(self, t: float) -> None:
        got = self._states(t)
        if got is None:
            return
        states, laser_on = got
        bodies = []
        for r in self.robots:
            if r not in states:
                raise InputError(f"the reference gave no state for robot {r!r}", "reference")
            q, qd = states[r]
            body = {"schema": SETPOINT_SCHEMA, "robot": r, "t": t, "session": self.session_id,
                    "seq": self.seq, "id": self.request_id, "q": np.asarray(q, float).tolist(),
                    "qd": np.asarray(qd, float).tolist(),
                    "laser_on": bool(laser_on) and r == self.gate_robot,
                    "aim": self.aim and not laser_on and r == self.gate_robot}  # fmt: skip
            bodies.append((r, json.dumps(body, allow_nan=False).encode()))
        for r, data in bodies:  # every robot's body was built: none is sent half
            self._pubs[r].put(data)
        self.seq += 1


def _finite(x: Any, where: str) -> Array:
    a = np.asarray(x, dtype=float).reshape(-1)
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise InputError(f"expected finite joint values, got {a.tolist()}", where)
    return a
