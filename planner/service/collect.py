"""Calibration data collection over the bus (``beamrelay calibrate collect``).

The collector plays the planner for its own moves: it declares ``<prefix>/alive/planner``
and sends a heartbeat (100 Hz, its own session) so the robot drivers accept its
trajectories, and stops beating when it ends (the drivers then brake if anything still
moves). Given the bus address, the beats come from the planner's heartbeat process
(:class:`planner.service.heartbeat.HeartbeatProcess`: real-time priority where permitted,
ends with this process), so a loaded machine (the console's browser rendering) does not
silence them for the drivers' 100 ms; without it, from a thread of this process. For each planned pose (:mod:`planner.calibration.collect`): a minimum-jerk move
from the measured joints, checked with the swept collision check of the scene and the other
robots at their measured joints, sent as a ``JointTrajectory``; the collector waits for the
driver's verdict and for the arm to come to rest on the pose, then asks the camera:
``<prefix>/camera/markers`` (hand-eye) or the median of the next ``camera/spot`` messages
(beam). With a gated laser the spot is read under the aiming beam only: a hold trajectory
at the gate robot's joints with an ``aim_on`` interval (:meth:`BusPlanner.aimed_spot`); the
treatment gate never opens. A pose whose move fails the safety check, is refused, or is not
seen is skipped and reported. Joints in rad, points in m (camera optical frame).
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.bus.session import MAX_PAYLOAD_BYTES, Keys, decode, urgent
from planner.calibration.collect import min_jerk_move
from planner.errors import InputError
from planner.model.system import System
from planner.model.transforms import Array
from planner.service.heartbeat import BusAddress, HeartbeatError, HeartbeatProcess
from schemas.brakes import Brake, brake_of
from schemas.messages import JointState, JointTrajectory, RobotStatus, SpotMessage


class Why(str):
    """Why a move did not arrive: the operator's line (this string), and what a caller acts
    on, read once where the driver's words arrive: ``brake``, the driver's cause
    (:class:`schemas.brakes.Brake`; None for any other), and ``collided``, the move's own
    safety check found a collision (it was never sent)."""

    brake: Brake | None
    collided: bool

    def __new__(cls, text: str, brake: Brake | None = None, collided: bool = False) -> Why:
        why = super().__new__(cls, text)
        why.brake, why.collided = brake, collided
        return why

    @classmethod
    def driver(cls, head: str, reason: str | None) -> Why:
        """``head: reason``, with the cause the driver's ``reason`` begins with."""
        return cls(f"{head}: {reason}", brake_of(reason))

    @property
    def late_heartbeat(self) -> bool:
        """The driver braked or refused because planner heartbeats came late."""
        return self.brake is not None and self.brake.late_heartbeat

    def within(self, context: str) -> Why:
        """``context: self``, the same cause."""
        return Why(f"{context}: {self}", self.brake, self.collided)


ARRIVE = 2e-3  # rad: the arm counts as on the pose
SETTLE = 0.3  # s at rest before the camera is asked
AIM_HOLD = 1.5  # s the aiming beam is lit for one spot reading (10 frames at 30 Hz + latency)
#: largest trajectory body (bytes) of one leg of a move: under the bus limit with room
LEG_BYTES = 3 * MAX_PAYLOAD_BYTES // 4
MAX_LEGS = 1000
#: fraction of a joint's acceleration limit a collection move may use (the driver refuses more)
ACCEL_SHARE = 0.8


def trajectory_body(system: System, robot: str, ident: str, session: str, mv: Any) -> bytes:
    """The JointTrajectory body of one move ``mv`` (:class:`~planner.calibration.collect.Move`)."""
    names = list(system.robot(robot).joint_names)
    msg = JointTrajectory(robot=robot, id=ident, session=session, t=mv.t.tolist(), names=names,
                          q=mv.q.tolist(), qd=mv.qd.tolist(), qdd=mv.qdd.tolist())  # fmt: skip
    return msg.model_dump_json(by_alias=True).encode()


def legs(q0: Array, q1: Array, speed: float, size: Callable[[Any], int],
         max_bytes: int = LEG_BYTES, acceleration: Array | None = None) -> list[Array]:  # fmt: skip
    """Waypoints on the joint-space line from ``q0`` to ``q1`` (the last is ``q1``): as few
    equal legs as keep each leg's minimum-jerk body (``size(move)``, bytes) under
    ``max_bytes``."""
    n = 1
    while True:
        nbytes = size(min_jerk_move(q0, q0 + (q1 - q0) / n, speed, acceleration=acceleration))
        if nbytes <= max_bytes:
            return [q0 + (q1 - q0) * (k / n) for k in range(1, n + 1)]
        if n >= MAX_LEGS:  # a leg never gets shorter than the shortest move (0.5 s)
            raise InputError(f"a move of {nbytes} bytes per leg after {n} legs: "
                             f"{max_bytes} bytes cannot hold one", "move")  # fmt: skip
        n = min(MAX_LEGS, max(n + 1, int(np.ceil(1.1 * n * nbytes / max_bytes))))


class BusPlanner:
    """Heartbeat, planner token, joint states, statuses and spots of a collection run;
    ``bus``: the address of ``session`` (the heartbeat then comes from its own process)."""

    def __init__(self, session: Any, keys: Keys, system: System,
                 leg_bytes: int = LEG_BYTES, bus: BusAddress | None = None) -> None:  # fmt: skip
        self.session, self.keys, self.system = session, keys, system
        self.leg_bytes = leg_bytes  # largest body of one leg of a move
        self.name = f"collect-{uuid.uuid4().hex[:8]}"
        self.q: dict[str, Array] = {}
        self.status: dict[str, RobotStatus] = {}
        self.spots: deque[SpotMessage] = deque(maxlen=64)
        self._halt = threading.Event()
        s = session
        self._handles: list[Any] = [s.liveliness().declare_token(keys.alive("planner"))]
        for r in system.robot_names:
            self._handles += [
                s.declare_subscriber(keys.joint_states(r), self._on_joints(r)),
                s.declare_subscriber(keys.status(r), self._on_status(r)),
            ]
        self._handles.append(s.declare_subscriber(keys.camera_spot, self._on_spot))
        self._pub: Any = None
        self._beat: threading.Thread | None = None
        self._process: HeartbeatProcess | None = None
        self.silent: str | None = None  # why the heartbeat process stopped, if it did
        if bus is not None:
            self._process = self._start_process(bus)
        else:
            self._pub = s.declare_publisher(keys.heartbeat, **urgent())
            self._beat = threading.Thread(target=self._beats, daemon=True)
            self._beat.start()

    def _start_process(self, bus: BusAddress) -> HeartbeatProcess:
        process = HeartbeatProcess(bus, self.keys.heartbeat, self.name, _NeverOverdue(),
                                   self._on_silent)  # fmt: skip
        try:
            return process.start()
        except BaseException as exc:  # HeartbeatError, or SIGTERM/Ctrl-C while it starts
            process.stop()
            for h in reversed(self._handles):
                h.undeclare()
            if isinstance(exc, HeartbeatError):
                raise InputError(f"{exc}: is the system running on this bus?", "bus") from None
            raise

    def _on_silent(self, reason: str) -> None:
        self.silent = reason

    def _beats(self) -> None:
        seq = 0
        while not self._halt.wait(0.01):
            body = {"schema": "beamrelay.heartbeat/1", "t": time.time(), "session": self.name,
                    "seq": seq}  # fmt: skip
            self._pub.put(json.dumps(body).encode())
            seq += 1

    def _on_joints(self, robot: str) -> Any:
        def cb(sample: Any) -> None:
            with contextlib.suppress(InputError):
                self.q[robot] = np.asarray(decode(sample.payload.to_bytes(), JointState).q)

        return cb

    def _on_status(self, robot: str) -> Any:
        def cb(sample: Any) -> None:
            with contextlib.suppress(InputError):
                self.status[robot] = decode(sample.payload.to_bytes(), RobotStatus)

        return cb

    def _on_spot(self, sample: Any) -> None:
        with contextlib.suppress(InputError):
            self.spots.append(decode(sample.payload.to_bytes(), SpotMessage))

    def wait_joints(self, timeout: float = 10.0) -> dict[str, Array]:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if all(r in self.q for r in self.system.robot_names):
                return dict(self.q)
            time.sleep(0.02)
        missing = [r for r in self.system.robot_names if r not in self.q]
        raise InputError(f"no joint states from {', '.join(missing)} (drivers running?)", "bus")

    def wait_rest(self, robot: str, timeout: float = 5.0) -> bool:
        """Whether ``robot`` rests (idle, no fault) within ``timeout`` s."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            st = self.status.get(robot)
            if st is not None and st.mode == "idle" and st.fault is None and self.silent is None:
                return True
            time.sleep(0.02)
        return False

    def move(self, robot: str, target: Array, speed: float, world: Any) -> Why | None:
        """Move ``robot`` to ``target``; None when it arrived, else why not. A move whose
        body would pass ``leg_bytes`` goes as legs along the same joint-space line, each
        a minimum-jerk move from rest to rest sent when the last one arrived (a driver joins
        a trajectory only from rest; a slow or long move is a 30 s, 6 MB body at 500 Hz)."""
        if self.silent is not None:  # the drivers would refuse the move
            return Why(f"no heartbeat: {self.silent}")
        q0 = self.wait_joints()[robot]

        def size(mv: Any) -> int:
            return len(trajectory_body(self.system, robot, "x" * 12, self.name, mv))

        waypoints = legs(q0, np.asarray(target, dtype=float), speed, size, self.leg_bytes,
                         self._acceleration(robot))  # fmt: skip
        for k, waypoint in enumerate(waypoints):
            last = k == len(waypoints) - 1
            why = self._leg(robot, waypoint, speed, world, SETTLE if last else 0.0)
            if why is not None:
                return why if len(waypoints) == 1 else why.within(f"leg {k + 1}/{len(waypoints)}")
        return None

    def _acceleration(self, robot: str) -> Array:
        return ACCEL_SHARE * np.asarray(self.system.robot(robot).limits.acceleration, dtype=float)

    def _leg(
        self, robot: str, target: Array, speed: float, world: Any, settle: float
    ) -> Why | None:
        """One minimum-jerk move from the measured joints, checked, sent, waited for."""
        from planner.safety.sweep import check_sweep

        q_all = self.wait_joints()
        mv = min_jerk_move(q_all[robot], target, speed, acceleration=self._acceleration(robot))
        Q = np.hstack([np.tile(q_all[r], (len(mv.t), 1)) if r != robot else mv.q
                       for r in self.system.robot_names])  # fmt: skip
        hit = check_sweep(world, mv.t, Q)
        if hit is not None:
            return Why(f"safety check: {hit}", collided=True)
        ident = uuid.uuid4().hex[:12]
        body = trajectory_body(self.system, robot, ident, self.name, mv)
        if len(body) > MAX_PAYLOAD_BYTES:  # legs() keeps every leg far under it
            return Why(f"the move's body ({len(body)} bytes) exceeds {MAX_PAYLOAD_BYTES} bytes")
        self.session.put(self.keys.trajectory(robot), body)
        return self._arrive(robot, ident, target, float(mv.t[-1]) + 15.0, settle)

    def _arrive(self, robot: str, ident: str, target: Array, timeout: float,
                settle: float = SETTLE) -> Why | None:  # fmt: skip
        end, rest_since = time.monotonic() + timeout, None
        while time.monotonic() < end:
            st = self.status.get(robot)
            ack = None if st is None else st.trajectory
            if st is None or ack is None or ack.id != ident:  # not yet judged: older status
                time.sleep(0.01)
                continue
            if not ack.accepted:
                return Why.driver("refused by the driver", ack.reason)
            if st.mode in ("braking", "stopped", "fault"):
                return Why.driver(f"driver {st.mode}", st.fault)
            near = float(np.max(np.abs(self.q[robot] - target))) <= ARRIVE
            if near and st.mode == "idle":
                rest_since = rest_since or time.monotonic()
                if time.monotonic() - rest_since >= settle:
                    return None
            else:
                rest_since = None
            time.sleep(0.01)
        return Why("did not arrive in time")

    def markers(self, request: dict[str, Any], timeout: float = 5.0,
                attempts: int = 2) -> Array | None:  # fmt: skip
        """Board points seen now (P x 3, NaN = not seen), or None when the camera did not
        answer ``attempts`` requests of ``timeout`` s each (a camera busy on a loaded machine
        answers late; the arm rests meanwhile, so a second request sees the same pose)."""
        key = f"{self.keys.prefix}/camera/markers"
        for _ in range(attempts):
            for reply in self.session.get(key, payload=json.dumps(request).encode(),
                                          timeout=timeout):  # fmt: skip
                if reply.ok is None:
                    continue
                body = json.loads(reply.ok.payload.to_bytes())
                if "error" in body:
                    raise InputError(f"camera: {body['error']}", key)
                rows = body["points_camera"]
                return np.array([[np.nan] * 3 if p is None else p for p in rows], dtype=float)
        return None

    def spot(self, n: int = 10, min_confidence: float = 0.3, timeout: float = 3.0) -> Array | None:
        """Median of the next ``n`` spot messages with a spot (camera frame, m), or None."""
        self.spots.clear()
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            good = [s.p_camera for s in list(self.spots)
                    if s.p_camera is not None and s.confidence >= min_confidence]  # fmt: skip
            if len(good) >= n:
                return np.median(np.array(good, dtype=float), axis=0)
            time.sleep(0.02)
        return None

    def aimed_spot(self, gate_robot: str, n: int = 10) -> Array | None:
        """:meth:`spot` read while the aiming beam is lit: a hold of :data:`AIM_HOLD` s at
        ``gate_robot``'s joints with ``aim_on`` throughout (the treatment gate stays off)."""
        q = self.wait_joints()[gate_robot]
        t = np.linspace(0.0, AIM_HOLD, 16)
        rows, zeros = np.tile(q, (len(t), 1)).tolist(), np.zeros((len(t), len(q))).tolist()
        ident = uuid.uuid4().hex[:12]
        msg = JointTrajectory(robot=gate_robot, id=ident, session=self.name, t=t.tolist(),
                              names=list(self.system.robot(gate_robot).joint_names), q=rows,
                              qd=zeros, qdd=zeros, aim_on=[[0.0, AIM_HOLD]])  # fmt: skip
        self.session.put(self.keys.trajectory(gate_robot), msg.model_dump_json(by_alias=True))
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            st = self.status.get(gate_robot)
            ack = None if st is None else st.trajectory
            if ack is not None and ack.id == ident:
                if not ack.accepted:
                    raise InputError(f"{gate_robot} refused the aiming hold: {ack.reason}",
                                     "laser.aim")  # fmt: skip
                return self.spot(n, timeout=AIM_HOLD)
            time.sleep(0.01)
        return None

    def close(self) -> None:
        """Stop beating (an arm still moving brakes), undeclare everything."""
        self._halt.set()
        if self._process is not None:
            self._process.stop()
        if self._beat is not None:
            self._beat.join(2.0)
        if self._pub is not None:
            self._pub.undeclare()
        for h in reversed(self._handles):
            h.undeclare()


class _NeverOverdue:
    """The heartbeat process's progress check for the collector: nothing to watch beyond
    the ticks (a wedged collector stops ticking, and so stops the beats)."""

    def overdue(self) -> str | None:
        return None
