"""The Zenoh side of a robot driver, common to the ``sim`` and ``ur`` backends (SPEC section 6).

:class:`RobotNode` runs the backend's control loop in a thread (one
:meth:`RobotBackend.step` per period, 500 Hz by default) and

- publishes ``<prefix>/<robot>/joint_states`` (:class:`schemas.messages.JointState`, rad,
  rad/s, ``t`` = UNIX time) every ``rate / state_rate`` periods (250 Hz by default),
- publishes ``<prefix>/<robot>/status`` (:class:`schemas.messages.RobotStatus`) on every mode
  change and at 10 Hz,
- subscribes ``<prefix>/<robot>/trajectory`` (:class:`schemas.messages.JointTrajectory`) and
  hands accepted trajectories to the backend; a rejected one leaves the arm as it was and
  gets a status with ``fault = "trajectory rejected: <field>: <reason>"``,
- declares the liveliness token ``<prefix>/alive/<robot>`` and watches
  ``<prefix>/alive/planner``: when the planner's token disappears (its process died or was
  killed: Zenoh drops the token as soon as the transport closes) the backend brakes at the
  next period; trajectories are refused while no planner is alive.
"""

from __future__ import annotations

import threading
import time
from typing import Any, NamedTuple, Protocol

import numpy as np

from drivers.loop_node import LoopNode
from drivers.robot.follower import Reference
from planner.errors import InputError
from planner.model.system import Limits
from planner.model.transforms import Array
from planner.service.bus import JSON, Keys, decode, encode
from schemas.messages import JointState, JointTrajectory, RobotStatus

START_TOLERANCE = 0.01  # rad: largest |q_traj[0] - q_now| accepted (any joint)
LIMIT_SLACK = 1e-6  # relative slack on velocity/acceleration limits (numerical noise)


class Measured(NamedTuple):
    """The arm's state after one period: joints (rad, rad/s) and controller state."""

    q: Array
    qd: Array
    mode: str
    protective_stop: bool = False
    fault: str | None = None


class RobotBackend(Protocol):
    """What :class:`RobotNode` needs from a backend (see ``robot_sim`` / ``robot_ur``)."""

    kind: str
    names: tuple[str, ...]
    rate: float

    def begin_period(self) -> None: ...
    def step(self) -> Measured: ...
    def end_period(self) -> None: ...
    def measured(self) -> Measured: ...
    def command(self, reference: Reference) -> None: ...
    def brake(self, reason: str) -> None: ...
    def close(self) -> None: ...


def check_trajectory(
    msg: JointTrajectory,
    robot: str,
    names: tuple[str, ...],
    limits: Limits,
    q_now: Array,
    start_tolerance: float = START_TOLERANCE,
) -> Reference:
    """Validate a received trajectory against this arm; InputError(reason, field) if not.

    Checks: robot name, joint names (same order), the first sample within
    ``start_tolerance`` rad of ``q_now`` on every joint, and every sample inside the
    position limits and the velocity/acceleration limits (jerk is left to Ruckig's approach
    and the planner's timing).
    """
    if msg.robot != robot:
        raise InputError(
            f"trajectory is for robot {msg.robot!r}, this driver is {robot!r}", "robot"
        )
    if tuple(msg.names) != tuple(names):
        raise InputError(f"joint names {msg.names} differ from {list(names)}", "names")
    t = np.asarray(msg.t, dtype=float)
    q, qd, qdd = (np.asarray(a, dtype=float) for a in (msg.q, msg.qd, msg.qdd))
    gap = np.abs(q[0] - np.asarray(q_now, dtype=float))
    if np.max(gap) > start_tolerance:
        j = int(np.argmax(gap))
        raise InputError(
            f"starts {gap[j]:.4f} rad from the current state on joint {names[j]} "
            f"(tolerance {start_tolerance:g} rad)",
            "q[0]",
        )
    bounds = [
        ("q", q < limits.lower, limits.lower, "below lower limit"),
        ("q", q > limits.upper, limits.upper, "above upper limit"),
        ("qd", np.abs(qd) > limits.velocity * (1 + LIMIT_SLACK), limits.velocity, "exceeds"),
        (
            "qdd",
            np.abs(qdd) > limits.acceleration * (1 + LIMIT_SLACK),
            limits.acceleration,
            "exceeds",
        ),
    ]
    for key, bad, bound, what in bounds:
        if np.any(bad):
            k, j = (int(i) for i in np.argwhere(bad)[0])
            value = {"q": q, "qd": qd, "qdd": qdd}[key][k, j]
            raise InputError(
                f"{value:.4f} on joint {names[j]} {what} {bound[j]:.4f}", f"{key}[{k}]"
            )
    return Reference(t, q, qd, qdd)


class RobotNode(LoopNode):
    """Runs one backend on the bus (see the module docstring)."""

    def __init__(
        self,
        session: Any,
        keys: Keys,
        robot: str,
        backend: RobotBackend,
        limits: Limits,
        *,
        state_rate: float = 250.0,
        status_rate: float = 10.0,
        start_tolerance: float = START_TOLERANCE,
        require_planner: bool = True,
    ) -> None:
        super().__init__()
        self.session = session
        self.keys = keys
        self.robot = robot
        self.backend = backend
        self.limits = limits
        self.start_tolerance = start_tolerance
        self.require_planner = require_planner
        self._state_every = max(1, round(backend.rate / state_rate))
        self._status_every = max(1, round(backend.rate / status_rate))
        self._lock = threading.Lock()
        self.planner_alive = False
        self.planner_lost_at: float | None = None  # UNIX time the planner's token went away
        self.rejection: str | None = None
        self.n_accepted = 0
        self.n_rejected = 0

    # -- lifecycle ---------------------------------------------------------------------
    def start(self) -> RobotNode:
        s, k = self.session, self.keys
        self._pub_state = s.declare_publisher(k.joint_states(self.robot), encoding=JSON)
        self._pub_status = s.declare_publisher(k.status(self.robot), encoding=JSON)
        self._handles = [
            s.declare_subscriber(k.trajectory(self.robot), self._on_trajectory),
            s.liveliness().declare_subscriber(k.alive("planner"), self._on_planner, history=True),
            s.liveliness().declare_token(k.alive(self.robot)),
        ]
        self._start_loop(f"{self.robot}-control")
        return self

    def _close(self) -> None:
        """Stop the arm (backend ``close``)."""
        with self._lock:
            self.backend.close()

    # -- callbacks (Zenoh threads) -------------------------------------------------------
    def _on_planner(self, sample: Any) -> None:
        import zenoh

        alive = sample.kind == zenoh.SampleKind.PUT
        self.planner_alive = alive
        if not alive:
            self.planner_lost_at = time.time()
            with self._lock:
                self.backend.brake("planner liveliness lost")

    def _on_trajectory(self, sample: Any) -> None:
        try:
            if self.require_planner and not self.planner_alive:
                raise InputError("no planner alive (watchdog): not moving", "body")
            msg = decode(sample.payload.to_bytes(), JointTrajectory)
            with self._lock:
                ref = check_trajectory(
                    msg,
                    self.robot,
                    self.backend.names,
                    self.limits,
                    self.backend.measured().q,
                    self.start_tolerance,
                )
                self.backend.command(ref)
            self.rejection = None
            self.n_accepted += 1
        except InputError as exc:
            self.n_rejected += 1
            self.rejection = f"trajectory rejected: {exc}"
            self._publish_status(self.backend.measured())

    # -- control loop --------------------------------------------------------------------
    def _loop(self) -> None:
        tick, last_mode = 0, ""
        while not self._stop.is_set():
            self.backend.begin_period()
            with self._lock:
                m = self.backend.step()
            if tick % self._state_every == 0:
                self._pub_state.put(
                    encode(
                        JointState(
                            t=time.time(),
                            names=list(self.backend.names),
                            q=m.q.tolist(),
                            qd=m.qd.tolist(),
                        )
                    )
                )
            if m.mode != last_mode or tick % self._status_every == 0:
                self._publish_status(m)
                last_mode = m.mode
            tick += 1
            self.backend.end_period()

    def _publish_status(self, m: Measured) -> None:
        fault = m.fault or self.rejection
        if fault is None and not self.planner_alive and self.require_planner:
            fault = "no planner alive (watchdog)"
        msg = RobotStatus(
            robot=self.robot,
            t=time.time(),
            mode=m.mode,
            protective_stop=m.protective_stop,
            fault=fault,
        )
        self._pub_status.put(encode(msg))
