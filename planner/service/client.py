"""Client side of the planner node: send a TargetRequest, watch the motion, measure the spot.

:class:`PlanClient` wraps one Zenoh session (connecting to the bus endpoint). ``request``
sends a TargetRequest to ``<prefix>/plan`` and returns the plan.json dict (or raises
:class:`RequestError` with the node's :class:`~schemas.messages.ErrorReply`). While a
request executes, the client records every robot's ``joint_states`` and the camera's
``camera/spot``. A spot is placed by its capture time ``t`` (the camera's stamp, UNIX s) on
each robot's joint states by their stamps (the drivers and the camera share the host clock):
it arrives later than the frame was taken, after the arm may have moved on. It counts for
target k when every robot was at rest (|qd| below ``REST_QD`` rad/s) for the ``SETTLE`` s up
to its capture, within ``AT_TARGET_Q`` rad of the plan's solution ``q_k``. The measured spot of
target k is the mean of its samples, mapped to the world with the plan's camera pose.
"""
# long module: the planner's client: requests, execution, verdicts and the plan replies it parses share one session

from __future__ import annotations

import json
import threading
import time
import uuid
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from planner.bus.session import JSON, Keys, decode, encode, open_session
from planner.errors import BeamrelayError, InputError
from planner.io.plan import Plan, Verdict
from planner.io.plan_reports import ClosedLoopTarget
from planner.model.status import Status
from planner.model.transforms import Array, transform_points
from schemas.messages import JointState, RobotStatus, SpotMessage

#: a robot within AT_TARGET_Q of q_k (rad, every joint), slower than REST_QD (rad/s) for the
#: SETTLE s before a frame's capture (the joint states a simulated camera traced the frame
#: from travel the bus too) is "at k"
AT_TARGET_Q = 1e-4
REST_QD = 1e-3
SETTLE = 0.1
#: joint states kept per robot to place spots at their capture time (8 s at 500 Hz)
HISTORY = 4096
#: s a spot waits for the joint states of its capture time; later it is placed on the
#: latest ones and not counted as at rest (a robot that went silent)
PLACE_WAIT = 0.3


class RequestError(BeamrelayError):
    """The node answered with an error reply (``reply``: the ErrorReply dict) or not at all."""

    def __init__(self, reason: str, reply: dict[str, Any] | None = None) -> None:
        self.reason = reason
        self.reply = reply or {}
        super().__init__(reason)


def make_request(
    points: ArrayLike,
    *,
    frame: str = "world",
    normals: ArrayLike | None = None,
    path: bool = False,
    execute: bool = False,
    request_id: str | None = None,
    closed_loop: bool = False,
    dwell: float | None = None,
    tolerance: float | None = None,
) -> dict[str, Any]:
    """A TargetRequest dict; points/normals (K, 3) in ``frame``, metres; ``dwell`` s and the
    closed-loop ``tolerance`` m only when given."""
    req: dict[str, Any] = {
        "schema": "beamrelay.request/1",
        "id": request_id or uuid.uuid4().hex[:12],
        "frame": frame,
        "points": np.asarray(points, dtype=float).reshape(-1, 3).tolist(),
        "mode": "path" if path else "points",
        "execute": execute,
    }
    if normals is not None:
        req["normals"] = np.asarray(normals, dtype=float).reshape(-1, 3).tolist()
    if closed_loop:
        req["closed_loop"] = True
    for key, value in (("dwell", dwell), ("tolerance", tolerance)):
        if value is not None:
            req[key] = float(value)
    return req


def world_T_camera_of(plan: Plan) -> Array | None:
    """The camera pose the plan was made with (resolved scenario), or None (no camera, or
    one on a flange: its pose depends on the joints)."""
    return plan.resolved.world_T_camera


class Spot(NamedTuple):
    """A camera spot as the client recorded it."""

    arrived: float
    """receiver monotonic time of its arrival (s)"""
    p_camera: Array
    q: dict[str, Array]
    """every robot's joints at its capture"""
    rest: bool
    """every robot at rest for the SETTLE s before its capture"""
    t: float
    """its capture time (the camera's stamp, UNIX s)"""


@dataclass
class Recorder:
    """Joint states and spots seen on the bus, thread safe. ``joints``: the latest state of
    each robot (receiver monotonic time, q, qd); ``spots``: the spots placed on the joint
    states of their capture."""

    joints: dict[str, tuple[float, Array, Array]] = field(default_factory=dict)
    history: dict[str, deque[tuple[float, Array, Array]]] = field(default_factory=dict)
    """robot -> (stamp, UNIX s; q; qd) of its last HISTORY joint states"""
    spots: list[Spot] = field(default_factory=list)
    pending: deque[tuple[float, float, Array]] = field(default_factory=deque)
    """spots (arrival, capture stamp, p_camera) waiting for the joint states of their capture"""
    faults: dict[str, tuple[str | None, str]] = field(default_factory=dict)
    """robot -> (request id of its latest trajectory, fault text) while its driver reports a
    fault or a protective stop"""
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_joints(self, robot: str, q: Array, qd: Array, t: float | None = None) -> None:
        """A joint state stamped ``t`` (UNIX s; now when None)."""
        now = time.monotonic()
        stamp = time.time() if t is None else float(t)
        with self.lock:
            self.joints[robot] = (now, q, qd)
            h = self.history.setdefault(robot, deque(maxlen=HISTORY))
            if h and stamp < h[-1][0]:  # a restarted driver, or a clock step: start over
                h.clear()
            h.append((stamp, q, qd))
            self._place(now)

    def on_spot(self, p_camera: Array, t: float | None = None) -> None:
        """A spot captured at ``t`` (UNIX s; now when None), recorded once the joint states
        of that time are in."""
        now = time.monotonic()
        stamp = time.time() if t is None else float(t)
        with self.lock:
            self.pending.append((now, stamp, p_camera))
            self._place(now)

    def _place(self, now: float) -> None:
        """Record the pending spots whose capture the joint states reach (in order)."""
        while self.pending:
            arrived, stamp, p = self.pending[0]
            placed = self._joints_at(stamp, late=now - arrived > PLACE_WAIT)
            if placed is None:
                return
            self.pending.popleft()
            self.spots.append(Spot(arrived, p, *placed, stamp))

    def _joints_at(self, stamp: float, late: bool) -> tuple[dict[str, Array], bool] | None:
        """Every robot's joints at ``stamp`` and whether all rested for the SETTLE s before;
        None while a robot's states do not reach ``stamp`` yet (unless ``late``: then its
        latest, not at rest)."""
        q: dict[str, Array] = {}
        rest = True
        for robot, h in self.history.items():
            if not h:  # no state of this robot kept (cannot happen today: made with one)
                continue
            if h[-1][0] < stamp:
                if not late:
                    return None
                q[robot], rest = h[-1][1], False
                continue
            at: Array | None = None
            covered = False
            for t, qj, qdj in reversed(h):  # newest first: the window is near the end
                if t > stamp:
                    continue
                if at is None:
                    at = qj
                if (
                    float(np.max(np.abs(qdj))) >= REST_QD
                    or float(np.max(np.abs(qj - at))) >= AT_TARGET_Q
                ):
                    rest = False
                    break
                if t <= stamp - SETTLE:
                    covered = True
                    break
            if at is None:  # the capture precedes the kept states
                at, rest = h[0][1], False
            q[robot] = at
            rest = rest and covered
        return q, rest

    def on_status(self, robot: str, request: str | None, fault: str | None) -> None:
        """A driver's status: its latest trajectory's request id and its fault (None: ok)."""
        with self.lock:
            if fault is None:
                self.faults.pop(robot, None)
            else:
                self.faults[robot] = (request, fault)

    def fault_of(self, request: str | None) -> str | None:
        """``robot: fault`` of a driver that faulted while executing ``request``, or None."""
        with self.lock:
            bad = [f"{r}: {f}" for r, (rid, f) in sorted(self.faults.items()) if rid == request]
        return "; ".join(bad) or None

    def rest_time(self, robot: str) -> float:
        """How long (s, by its stamps) ``robot`` has rested up to its latest joint state;
        0 while moving or unknown."""
        with self.lock:
            h = self.history.get(robot)
            if not h or float(np.max(np.abs(h[-1][2]))) >= REST_QD:
                return 0.0
            since = h[-1][0]
            for t, _, qd in reversed(h):
                if float(np.max(np.abs(qd))) >= REST_QD:
                    break
                since = t
            return h[-1][0] - since

    def moving(self) -> bool:
        with self.lock:
            return any(float(np.max(np.abs(v[2]))) >= REST_QD for v in self.joints.values())

    def rests_at(self, q_end: dict[str, Array]) -> bool:
        """Whether every robot of ``q_end`` (rad) is at rest within AT_TARGET_Q of it; with
        no joint state of a robot, whether the robots seen are at rest."""
        with self.lock:
            seen = {r: v for r, v in self.joints.items() if r in q_end}
            if len(seen) < len(q_end):
                return not any(float(np.max(np.abs(v[2]))) >= REST_QD for v in self.joints.values())
            return all(
                float(np.max(np.abs(v[2]))) < REST_QD
                and float(np.max(np.abs(v[1] - q_end[r]))) < AT_TARGET_Q
                for r, v in seen.items()
            )


def measured_spots(plan: Plan, rec: Recorder, since: float) -> list[Array | None]:
    """Median measured spot (world, m) per solution of ``plan``; None where never seen."""
    world_T_camera = world_T_camera_of(plan)
    if world_T_camera is None:
        raise InputError("the plan's scenario has no camera: spots cannot be measured")
    with rec.lock:
        samples = [s for s in rec.spots if s.arrived >= since and s.rest]
    out: list[Array | None] = []
    for sol in plan.solutions:
        if sol.status is not Status.OK:
            out.append(None)
            continue
        qk = sol.q
        hits = [
            s.p_camera
            for s in samples
            if all(r in s.q and float(np.max(np.abs(s.q[r] - qk[r]))) < AT_TARGET_Q for r in qk)
        ]
        if not hits:
            out.append(None)
            continue
        p_camera = np.mean(np.asarray(hits), axis=0)
        out.append(transform_points(world_T_camera, p_camera[None])[0])
    return out


class PlanClient:
    """A connected client session. Use as a context manager. With a Zenoh config file it
    waits up to ``connect_timeout`` s for the bus host (see :func:`planner.bus.session.zenoh_config`)."""

    def __init__(
        self,
        *,
        endpoint: str | None = None,
        prefix: str = "beamrelay",
        zenoh_config: Path | None = None,
        connect_timeout: float | None = 10.0,
    ) -> None:
        self.keys = Keys(prefix)
        self.session = open_session(
            listen=False,
            endpoint=endpoint,
            config_file=zenoh_config,
            connect_timeout=connect_timeout,
        )
        self.recorder = Recorder()
        #: why the last :meth:`execute` motion did not run to its end (a driver's fault, a
        #: stop, robots not at rest at the end in time), None when it did or nothing moved
        self.interruption: str | None = None
        self._subs: list[Any] = []
        self._watching = False

    def __enter__(self) -> PlanClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self._subs.clear()
        self.session.close()

    def watch(self) -> None:
        """Record every robot's joint states and the camera spot from now on (idempotent)."""

        if self._watching:
            return
        self._watching = True

        def joint_cb(sample: Any) -> None:
            robot = str(sample.key_expr).split("/")[-2]
            try:
                m = decode(sample.payload.to_bytes(), JointState)
            except InputError:
                return
            self.recorder.on_joints(robot, np.asarray(m.q), np.asarray(m.qd), m.t)

        def spot_cb(sample: Any) -> None:
            try:
                m = decode(sample.payload.to_bytes(), SpotMessage)
            except InputError:
                return
            if m.p_camera is not None:
                self.recorder.on_spot(np.asarray(m.p_camera), m.t)

        def status_cb(sample: Any) -> None:
            robot = str(sample.key_expr).split("/")[-2]
            try:
                m = decode(sample.payload.to_bytes(), RobotStatus)
            except InputError:
                return
            fault = "protective stop" if m.protective_stop else m.fault
            self.recorder.on_status(robot, m.trajectory.id if m.trajectory else None, fault)

        self._subs.append(self.session.declare_subscriber(self.keys.status("*"), status_cb))
        self._subs.append(self.session.declare_subscriber(self.keys.joint_states("*"), joint_cb))
        self._subs.append(self.session.declare_subscriber(self.keys.camera_spot, spot_cb))

    def wait_for_node(self, node: str, timeout: float = 10.0) -> bool:
        """Block until ``<prefix>/alive/<node>`` exists (True) or ``timeout`` s pass."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            replies = list(self.session.liveliness().get(self.keys.alive(node), timeout=0.5))
            if any(r.ok is not None for r in replies):
                return True
            time.sleep(0.05)
        return False

    def request_raw(self, payload: bytes, timeout: float = 10.0) -> tuple[bool, bytes]:
        """Send a raw body to ``<prefix>/plan``: (ok, reply body). RequestError on no reply."""
        replies = self.session.get(self.keys.plan, payload=payload, encoding=JSON, timeout=timeout)
        for reply in replies:
            if reply.ok is not None:
                return True, reply.ok.payload.to_bytes()
            return False, reply.err.payload.to_bytes()
        raise RequestError(f"no reply from the planner on {self.keys.plan} within {timeout:g} s")

    def request(self, req: dict[str, Any], timeout: float = 10.0) -> dict[str, Any]:
        """Send a TargetRequest dict; the plan.json dict, or RequestError with the error."""
        ok, body = self.request_raw(encode(req), timeout)
        data = json.loads(body)
        if not ok:
            where = f"{data.get('field')}: " if data.get("field") else ""
            raise RequestError(f"planner error: {where}{data.get('error')}", data)
        return dict(data)

    def plan(self, req: dict[str, Any], timeout: float = 10.0) -> Plan:
        """Send a TargetRequest dict; the :class:`~planner.io.plan.Plan` of the reply, or
        RequestError with the error."""
        return Plan.from_document(self.request(req, timeout))

    def execute(
        self, req: dict[str, Any], timeout: float = 10.0, settle: float = 0.4
    ) -> tuple[dict[str, Any], list[Array | None]]:
        """:meth:`execute_plan` with the reply as its plan.json document."""
        plan, spots = self.execute_plan(req, timeout, settle)
        return plan.to_document(), spots

    def execute_plan(
        self, req: dict[str, Any], timeout: float = 10.0, settle: float = 0.4
    ) -> tuple[Plan, list[Array | None]]:
        """Request with ``execute: true``, wait for the motion, return (plan, measured spots).

        Waits the trajectory's duration, then until every robot rests on the trajectory's
        final joints (at most ``timeout`` s more), then ``settle`` seconds more so the camera
        sees the final target; stops waiting when a driver reports a fault or a protective
        stop on this request's trajectory (a lost heartbeat, STOP); returns at once when the drivers
        rejected the trajectory (``plan.execution``); :attr:`interruption` says why a motion
        did not run to its end. Spots are None where not measured
        (all of them when rejected, or when the plan's scenario has no fixed camera).
        """
        self.watch()
        self.interruption = None
        since = time.monotonic()
        if req.get("closed_loop"):  # the node measured: the reply comes after the motion
            plan = self.plan({**req, "execute": True}, timeout)
            return plan, closed_loop_spots(plan)
        plan = self.plan({**req, "execute": True}, timeout)
        unmeasured: list[Array | None] = [None] * len(plan.solutions)
        if plan.execution is Verdict.REJECTED:  # nothing moves: nothing to wait for
            return plan, unmeasured
        traj = plan.trajectory
        duration = float(traj.t[-1]) if traj is not None and len(traj.t) else 0.0
        q_end = {} if traj is None else {r: q[-1] for r, q in traj.q.items() if len(q)}
        started = time.monotonic()
        deadline = started + duration + timeout
        # the arm may run late (a dwell looks like the end): wait until it rests at the end,
        # or a driver reports that it stopped this trajectory (a fault, a protective stop)
        reached = False
        while time.monotonic() < deadline and self.recorder.fault_of(plan.id) is None:
            if time.monotonic() - started >= duration and self.recorder.rests_at(q_end):
                reached = True
                break
            time.sleep(0.02)
        self.interruption = self.recorder.fault_of(plan.id)
        if self.interruption is None and not reached:
            self.interruption = (f"the robots did not come to rest at the trajectory's end "
                                 f"within {duration + timeout:.1f} s")  # fmt: skip
        time.sleep(settle)
        if world_T_camera_of(plan) is None:  # no camera (or one on a flange): not measured
            return plan, unmeasured
        return plan, measured_spots(plan, self.recorder, since)


def closed_loop_spots(plan: Plan) -> list[Array | None]:
    """The node's last measured spot (world, m) per target of a closed-loop reply."""
    n = len(plan.solutions)
    return [None] * n if plan.closed_loop is None else plan.closed_loop.spots(n)


def closed_loop_row(row: ClosedLoopTarget) -> dict[str, Any]:
    """A closed-loop row's figures in a request summary (JSON data; None where the row has
    none): status, iterations, frames, time (s), measured error before and after (m), dwell
    (s), treated, reason and detail, and the camera-frame figures (m)."""
    s = row.servo

    def run(key: str) -> Any:
        return None if s is None else getattr(s, key)

    return {"status": row.status, "iterations": run("iterations"), "frames": run("frames"),
            "time": run("time"), "measured_error_before": run("error_before"),
            "measured_error_after": run("error_after"), "dwell": row.dwell,
            "treated": row.treated, "reason": row.reason,
            "detail": row.detail,
            "measured_error_camera": row.error_camera,
            "measured_spot_camera": _list(row.spot_camera),
            "target_camera": _list(row.target_camera)}  # fmt: skip


def _list(x: Array | None) -> list[float] | None:
    return None if x is None else x.tolist()


def request_summary(plan: Plan, spots: list[Array | None] | None) -> dict[str, Any]:
    """The figures of one answered request, as plain JSON data: ``id``, ``execution`` and
    ``execution_reason`` (None when not executed), ``n_ok``, ``n_targets``, per target its
    status, reason, planned error and measured error (m; None when not seen; from the
    requested point of a camera-frame target that landed on its surface, which the camera
    saw), and over the measured targets ``measured_error_median`` / ``measured_error_max`` (m)."""
    rows = []
    errors = measured_errors(plan, spots)
    measured = [e for e in errors if e is not None]
    report = plan.closed_loop
    servo_rows = None if report is None else report.targets
    for k, sol in enumerate(plan.solutions):
        spot, err = None if spots is None else spots[k], errors[k]
        p = plan.targets.p[k]
        surface = None if sol.surface is None else sol.surface.to_document()
        rows.append({"id": int(plan.targets.ids[k]), "p": p.tolist(), "status": sol.status,
                     "reason": sol.reason, "planned_error": _finite(sol.error),
                     "measured_spot": None if spot is None else np.asarray(spot).tolist(),
                     "measured_error": err, "surface": surface})  # fmt: skip
        if servo_rows is not None and k < len(servo_rows):
            rows[-1]["closed_loop"] = closed_loop_row(servo_rows[k])
    out: dict[str, Any] = {
        "id": plan.id,
        "execution": plan.execution,
        "execution_reason": plan.execution_reason,
        "execution_unanswered": list(plan.execution_unanswered or []),
        "n_ok": plan.metrics.n_ok,
        "n_targets": plan.metrics.n_targets,
        "duration": plan.metrics.duration,
        "warnings": list(plan.warnings or []),
    }
    if measured:
        out["measured_error_median"] = float(np.median(measured))
        out["measured_error_max"] = float(np.max(measured))
        out["n_measured"] = len(measured)
    if report is not None:
        before = [r.servo.error_before for r in report.targets
                  if r.servo is not None and r.servo.error_before is not None]  # fmt: skip
        if before:
            out["measured_error_before_median"] = float(np.median(before))
            out["measured_error_before_max"] = float(np.max(before))
        out["closed_loop"] = report.to_document(targets=False)
    out["targets"] = rows
    return out


def measured_errors(plan: Plan, spots: list[Array | None] | None) -> list[float | None]:
    """Each target's measured error (m; None when not seen): the distance of its measured
    spot from its point, or from the requested point of a camera-frame target that landed
    on its surface (which the camera saw)."""
    out: list[float | None] = []
    for k, sol in enumerate(plan.solutions):
        spot = None if spots is None else spots[k]
        aim = plan.targets.p[k] if sol.surface is None else sol.surface.requested
        out.append(None if spot is None else float(np.linalg.norm(spot - aim)))
    return out


def _finite(x: Any) -> float | None:
    return float(x) if isinstance(x, int | float) and np.isfinite(x) else None
