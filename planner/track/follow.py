"""Following a moving target: tracker frames in, joint setpoints and the laser gate out.

Pure (no bus, no threads, no clock: every call takes its time ``now``, s on the sender's
clock). :class:`TargetFollower`, per tracker frame (:meth:`~TargetFollower.on_frame`):

1. feeds the measured point (world, m, captured at ``t``) to the predictor (a
   :class:`~planner.track.predict.KalmanCV` by default) with the D435 covariance of a point
   at that place (:class:`~planner.track.noise.MarkerNoise`);
2. predicts the target at ``t_a = now + lead`` (when a setpoint sent now takes effect) and at
   ``t_b = t_a + frame period``, and solves the beam IK for both, continuity-aware: the
   closed-form member nearest the current command (:class:`~planner.ik.BeamIK` warm-started
   at it, with the scenario's safety rules);
3. the reference ``q_ref(t)`` is the line through (t_a, q_a) and (t_b, q_b).

Per setpoint (:meth:`~TargetFollower.setpoint`, 500 Hz) the reference goes through a limiter
(per joint: velocity within the limits, velocity change per period within the acceleration
limits, a first-order pull of time constant ``pull`` onto the reference), so consecutive
setpoints never break a limit. The laser is on only while ``confidence`` x the prediction's
RMS error plus the commanded-vs-reached gap (the beam Jacobian times the limiter's lag and
the measured arm's lag behind the command) is under ``tolerance``, and the stream is fresh.

Every setpoint is checked, before it is sent, under the same rules as a planned sample
(the IK's :class:`~planner.safety.model.Safety`: arm-arm, arm-self, arm-scene, and the beam
at the predicted target against every arm part and keep-out volume), and so is the sweep
from the last setpoint to it: the joints on the line between them are checked at steps of at
most :data:`SWEEP_JOINT_STEP` rad (any joint) and :data:`SWEEP_SPOT_STEP` m of spot motion
on the target plane (through the spot Jacobian), so a volume the beam would sweep through
between two setpoints is found unless it is thinner than that step. A setpoint that breaks
a rule is not sent: the follower stops as *unsafe* (:attr:`TargetFollower.unsafe`), and the
session publishes a stop. The limiter also caps the spot's speed on the target plane at
``max_spot_speed`` (m/s, through the spot Jacobian).

Keep-out volumes attached to the target (``keep_out[].attached_to``, :attr:`attached`) move
with it: before each frame's solves they are placed at their scenario pose moved as the
tracked object moved. With :attr:`markers` (3 or more of the object's points at rest) and a
frame carrying the same points, that is the object's rigid motion (a least-squares fit,
turns included) from rest to the frame, advanced by the markers' centroid's predicted
displacement since the frame (a Kalman filter of its own: the target sliding on the object
does not drag the volumes); otherwise the predicted target's displacement from the first
estimate (translation only), so the eyes move, and turn, with the face.

The follower *stops* (laser off, no more setpoints; :attr:`TargetFollower.stopped` says
why) when no frame came for ``stale_frames`` frame periods, when a predicted target has no
safe solution (unreachable, outside the ROI, joint limits, a safety rule) or leaves the
region ``max_excursion`` (m) around the first estimate, when a frame's solution is more than
``max_jump`` (rad, any joint) from the current command (the member nearest it lies in
another posture: the arm is never swept there), or on :meth:`stop`.
"""
# long module: one follower: per frame it predicts, solves, gates the laser and limits the setpoints against one shared state

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.beam.trace import beam_vertices, trace_beam
from planner.calibration.handeye import fit_rigid
from planner.ik import BeamIK
from planner.model.transforms import Array
from planner.track.noise import MarkerNoise
from planner.track.predict import ConstantVelocity, KalmanCV, Prediction
from schemas import defaults

#: m: default largest predicted error with the laser on
TRACK_TOLERANCE = 1e-3
#: rad: the spot Jacobian is taken again when the joints moved this far from where it was
JACOBIAN_REUSE = 0.01
#: rad: largest joint step between two configurations checked on the sweep between setpoints
SWEEP_JOINT_STEP = 1e-3
#: m: largest spot step (target plane) between two configurations checked on that sweep
SWEEP_SPOT_STEP = 2e-4
#: fewest markers whose rigid motion moves the attached volumes
MIN_MARKERS = 3
#: m: RMS distance of the markers from their rigid fit beyond which a frame stops tracking
#: (the markers are sub-millimetre measurements; a swapped or moved marker is centimetres)
MAX_MARKER_RESIDUAL = 0.003


@dataclass(frozen=True)
class TrackSettings:
    """How a moving target is followed (SI units; see the module docstring)."""

    rate: float = defaults.SERVO_RATE_HZ  # Hz, setpoints
    frame_rate: float = 30.0  # Hz, tracker frames expected
    lead: float = 2.0 / defaults.SERVO_RATE_HZ  # s, a setpoint's time ahead of its sending
    tolerance: float = TRACK_TOLERANCE  # m
    confidence: float = 2.0  # sigmas of the prediction counted in the predicted error
    stale_frames: float = 3.0  # frame periods without a frame before the stop
    max_excursion: float = 0.1  # m, around the first estimate
    max_jump: float = 0.2  # rad, largest joint change of one frame's solution
    pull: float = 4.0 / defaults.SERVO_RATE_HZ  # s, limiter time constant
    max_spot_speed: float = 0.2  # m/s, the spot's speed on the target plane (a face's motion)

    @property
    def stale_after(self) -> float:
        """Seconds without a frame after which the stream counts as stale."""
        return self.stale_frames / self.frame_rate


@dataclass(frozen=True)
class FrameOutcome:
    """What one frame did: the prediction at ``t_a``, the solve time (s), the stop reason
    (None while following)."""

    prediction: Prediction | None
    solve_time: float
    stopped: str | None


@dataclass
class FrameSegment:
    """A frame's reference: the line through (t_a, q_a) and (t_b, q_b) (s, rad)."""

    t_a: float
    q_a: Array
    t_b: float
    q_b: Array
    sigma: float  # m, prediction RMS at t_b
    J: Array  # 3 x nq spot Jacobian at q_a (m/rad)
    normal: Array | None
    target_b: Array
    object_T_rest: Array = field(default_factory=lambda: np.eye(4))  # attached volumes' move

    def q_ref(self, t: float) -> tuple[Array, Array]:
        qd = (self.q_b - self.q_a) / (self.t_b - self.t_a)
        return self.q_a + (t - self.t_a) * qd, qd


@dataclass
class TargetFollower:
    """One tracked target (see the module docstring). ``q0``: stacked joints (rad) at the
    start; ``first``: the target's first estimate (m, world); ``world_T_camera`` gives the
    measurement noise (None: the measurement covariance must be passed to ``on_frame``)."""

    ik: BeamIK
    q0: Array
    first: Array
    world_T_camera: Array | None
    settings: TrackSettings = field(default_factory=TrackSettings)
    noise: MarkerNoise = field(default_factory=MarkerNoise)
    predictor: KalmanCV | ConstantVelocity = field(default_factory=KalmanCV)
    attached: dict[str, Array] = field(default_factory=dict)
    """keep-out volumes that move with this target: name -> pose (4 x 4, world, m) with the
    target at ``first``"""
    markers: Array | None = None
    """the tracked object's points at rest (K x 3, world, m; K >= 3), matched by index to a
    frame's ``markers``: their rigid motion moves :attr:`attached`"""
    check: Any = None
    """the rules every setpoint is checked under (:class:`~planner.safety.model.Safety`;
    default: the IK's own)"""

    def __post_init__(self) -> None:
        if self.check is None:
            self.check = getattr(self.ik, "safety", None)
        s = self.ik.system
        lim = s.limits
        self._vmax, self._amax = lim.velocity, lim.acceleration
        self._lower, self._upper = lim.lower, lim.upper
        self.q = np.asarray(self.q0, dtype=float).copy()  # the limiter's output
        self.qd = np.zeros_like(self.q)
        self.t_last: float | None = None  # the last setpoint's time
        self.segment: FrameSegment | None = None
        self.frame_seen: float | None = None  # ``now`` of the last frame
        self.stopped: str | None = None
        self.unsafe = False  # stopped because a setpoint broke a safety rule
        self.checked = 0  # setpoints checked against the safety rules
        self.arm_gap = 0.0  # m, spot offset of the measured arm from the command
        self.keep_out_shift = np.zeros(3)  # m, how far the attached volumes were moved
        self.object_T_rest = np.eye(4)  # the attached volumes' move for the setpoints
        self._fit: tuple[Array, Array] | None = None  # the markers' rigid fit, their centroid
        self._centroid = KalmanCV()  # the markers' centroid (world, m)
        self._J: Array | None = None  # spot Jacobian (m/rad), reused near where it was taken
        self._J_at = self.q

    # --- frames ----------------------------------------------------------------------------
    def on_frame(
        self, t: float, point: Array, normal: Array | None, now: float, R: Array | None = None,
        markers: Array | None = None,
    ) -> FrameOutcome:  # fmt: skip
        """A tracker frame: ``point`` (m, world) captured at ``t`` (s), received at ``now``;
        ``markers``: the frame's points matched to :attr:`markers` (K x 3, world, m).
        :meth:`solve_frame` then :meth:`commit`, in one go."""
        out, segment = self.solve_frame(t, point, normal, now, R, markers)
        if segment is not None:
            self.commit(segment)
        return out

    def solve_frame(
        self, t: float, point: Array, normal: Array | None, now: float, R: Array | None = None,
        markers: Array | None = None,
    ) -> tuple[FrameOutcome, FrameSegment | None]:  # fmt: skip
        """The prediction and solves of a frame (see :meth:`on_frame`), without touching
        what the setpoints read: the reference to :meth:`commit` (None: stopped). Run it on
        the frames' thread while another sends setpoints only when :attr:`check` is not the
        IK's own rules (a twin of them)."""
        t0 = time.perf_counter()
        if self.stopped is not None:
            return FrameOutcome(None, 0.0, self.stopped), None
        p = np.asarray(point, dtype=float)
        if R is None:
            if self.world_T_camera is None:
                raise ValueError("no camera pose and no measurement covariance")
            R = self.noise.covariance_world(p, self.world_T_camera)
        self.predictor.update(t, p, R)
        self.frame_seen = now
        lost = self._fit_markers(t, markers, R)
        if lost is not None:
            return self._halt(lost, t0)
        st = self.settings
        t_a = now + st.lead
        t_b = t_a + 1.0 / st.frame_rate
        pa, pb = self.predictor.predict(t_a), self.predictor.predict(t_b)
        n = None if normal is None else np.asarray(normal, dtype=float)
        for pred in (pa, pb):
            away = float(np.linalg.norm(pred.p - self.first))
            if away > st.max_excursion:
                return self._halt(f"target {1e3 * away:.1f} mm from its first estimate "
                                  f"(limit {1e3 * st.max_excursion:.0f} mm)", t0)  # fmt: skip
        segment = self.segment
        q_from = self.q if segment is None else segment.q_ref(t_a)[0]
        self._place(getattr(self.ik, "safety", None), self._attached_move(pa.p, t_a))
        sol_a = self.ik.solve(pa.p, n, q_from)
        sol_b = self.ik.solve(pb.p, n, sol_a.q) if sol_a.ok else sol_a
        if not (sol_a.ok and sol_b.ok) or sol_a.q is None or sol_b.q is None:
            bad = sol_a if not sol_a.ok else sol_b
            reason = bad.reason.value if bad.reason is not None else "failed"
            return self._halt(f"predicted target {np.round(pb.p, 4).tolist()} m: {reason}", t0)
        jump = float(np.abs(sol_a.q - q_from).max())
        if jump > st.max_jump:
            return self._halt(f"the solution for {np.round(pa.p, 4).tolist()} m is {jump:.3f}"
                              f" rad from the command (limit {st.max_jump:g} rad)", t0)  # fmt: skip
        if self._J is None or np.abs(sol_a.q - self._J_at).max() > JACOBIAN_REUSE:
            self._J, self._J_at = self._jacobian(sol_a.q, pa.p, n), sol_a.q
        seg = FrameSegment(t_a, sol_a.q, t_b, sol_b.q, pb.sigma, self._J, n, pb.p)
        seg.object_T_rest = self._attached_move(pb.p, t_b)
        return FrameOutcome(pa, time.perf_counter() - t0, None), seg

    def commit(self, segment: FrameSegment) -> None:
        """Make a solved frame's reference the one the setpoints follow, and place the
        attached volumes of :attr:`check` for it (quick: hold the setpoints' lock)."""
        if self.stopped is not None:
            return
        self.segment = segment
        if self.attached:
            self._place(self.check, segment.object_T_rest)
            self.object_T_rest = segment.object_T_rest
            D = segment.object_T_rest
            self.keep_out_shift = D[:3, :3] @ self.first + D[:3, 3] - self.first

    def _fit_markers(self, t: float, markers: Array | None, R: Array) -> str | None:
        """The object's rigid motion from rest to the frame captured at ``t`` (s), from the
        matched markers (``R``: one point's measurement covariance, m^2). When volumes
        follow markers, a frame whose markers are missing, malformed or do not move
        rigidly (RMS residual over :data:`MAX_MARKER_RESIDUAL`) is a reason to stop: the
        volumes' place is then unknown (they are never moved on by extrapolation alone)."""
        if self.markers is None or len(self.markers) < MIN_MARKERS:
            return None
        seen = None if markers is None else np.asarray(markers, dtype=float)
        if seen is None or seen.shape != self.markers.shape or not np.all(np.isfinite(seen)):
            return "the markers of the attached keep-out volumes are missing from the frame"
        fit = fit_rigid(self.markers, seen)
        moved = self.markers @ fit[:3, :3].T + fit[:3, 3]
        rms = float(np.sqrt(np.mean(np.sum((seen - moved) ** 2, axis=1))))
        if rms > MAX_MARKER_RESIDUAL:
            return (f"the markers do not move rigidly (RMS residual {1e3 * rms:.1f} mm, limit "
                    f"{1e3 * MAX_MARKER_RESIDUAL:g} mm): the keep-out volumes' place is unknown")  # fmt: skip
        centroid = seen.mean(axis=0)
        self._centroid.update(t, centroid, np.asarray(R) / len(seen))
        self._fit = fit, centroid
        return None

    def _attached_move(self, p: Array, t: float) -> Array:
        """How the attached volumes move (4 x 4, world) from rest at time ``t`` (s): the
        markers' rigid motion moved on by their centroid's predicted displacement, or else
        translated by ``p - first`` (``p``: the predicted target then)."""
        D = np.eye(4)
        if self._fit is None:
            D[:3, 3] = np.asarray(p, dtype=float) - self.first
        else:
            fit, centroid = self._fit
            D[:] = fit
            D[:3, 3] += self._centroid.predict(t).p - centroid
        return D

    def _place(self, safety: Any, D: Array) -> None:
        """Place the attached volumes of ``safety`` (:attr:`attached`: name -> their pose
        with the target at :attr:`first`) moved by ``D``."""
        if self.attached and safety is not None:
            safety.move_keep_out({name: D @ T for name, T in self.attached.items()})

    def release(self) -> None:
        """Put the attached keep-out volumes back at their scenario poses (the IK's safety
        rules are shared with later plans)."""
        for safety in {id(x): x for x in (getattr(self.ik, "safety", None), self.check)}.values():
            self._place(safety, np.eye(4))

    def warm_up(self, q: Array, normal: Array | None) -> None:
        """Run the per-frame computations once at ``q`` (rad) on the first estimate, so the
        first frame does not pay for first calls (caches, lazily built models)."""
        self.ik.solve(self.first, normal, q)
        self._J, self._J_at = self._jacobian(q, self.first, normal), np.asarray(q, dtype=float)
        if self.check is not None:  # its collision world is built on first use
            tr = trace_beam(self.ik.system, q, self.first, normal)
            self.check.config(q, beam_vertices(self.ik.system, tr.hits, tr.spot))

    def _halt(self, reason: str, t0: float) -> tuple[FrameOutcome, None]:
        self.stop(reason)
        return FrameOutcome(None, time.perf_counter() - t0, reason), None

    def _jacobian(self, q: Array, target: Array, normal: Array | None) -> Array:
        """Spot on the target plane w.r.t. q (3 x nq, m/rad), forward differences."""
        h = 1e-7
        s0 = trace_beam(self.ik.system, q, target, normal).spot
        cols = []
        for j in range(len(q)):
            dq = np.zeros_like(q)
            dq[j] = h
            cols.append((trace_beam(self.ik.system, q + dq, target, normal).spot - s0) / h)
        return np.column_stack(cols)

    def _spot_speed_cap(self, qd: Array, cap: float, dt: float) -> Array:
        """``qd`` (inside the acceleration box of ``dt`` s around ``self.qd``) scaled down to
        a spot speed ``|J qd|`` of at most ``cap`` (m/s), then kept inside the box; the
        direction stays the limiter's, so the spot still heads for the reference."""
        assert self.segment is not None
        v = float(np.linalg.norm(self.segment.J @ qd))
        if v <= cap:
            return qd
        step = self._amax * dt
        return np.asarray(np.clip(qd * (cap / v), self.qd - step, self.qd + step))

    def sweep_steps(self, q_from: Array, q_to: Array) -> int:
        """How many equal steps the line from ``q_from`` to ``q_to`` (rad) is checked in: at
        most :data:`SWEEP_JOINT_STEP` per joint and :data:`SWEEP_SPOT_STEP` of spot motion."""
        dq = np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float)
        n = float(np.abs(dq).max()) / SWEEP_JOINT_STEP
        if self.segment is not None:
            n = max(n, float(np.linalg.norm(self.segment.J @ dq)) / SWEEP_SPOT_STEP)
        return max(1, int(np.ceil(n)))

    def _violation(self, q: Array) -> str | None:
        """Why a setpoint at stacked ``q`` (rad), or the sweep to it from the last one
        (:attr:`q`), breaks a safety rule, with the beam at the predicted target; None when
        neither breaks any (or there are no rules)."""
        if self.check is None or self.segment is None:
            return None
        n = self.sweep_steps(self.q, q)
        for k in range(1, n + 1):
            bad = self._config_violation(self.q + (q - self.q) * (k / n))
            if bad is not None:
                return bad if k == n else f"{bad} (on the sweep, {k}/{n} of the way)"
        return None

    def _config_violation(self, q: Array) -> str | None:
        assert self.segment is not None
        system = self.ik.system
        tr = trace_beam(system, q, self.segment.target_b, self.segment.normal)
        self.checked += 1
        bad = self.check.config(q, beam_vertices(system, tr.hits, tr.spot))
        return None if bad is None else f"{bad.reason}: {bad.text}"

    def on_joint_state(self, q_measured: Array, t: float) -> None:
        """The arm's measured joints (stacked, rad) at ``t`` (s): its spot gap from the
        command then (m) counts in the predicted error."""
        if self.segment is None:
            return
        q_cmd, _ = self.segment.q_ref(t)
        self.arm_gap = float(np.linalg.norm(self.segment.J @ (np.asarray(q_measured) - q_cmd)))

    # --- setpoints -------------------------------------------------------------------------
    def stop(self, reason: str) -> None:
        """Stop following (idempotent: the first reason stays)."""
        if self.stopped is None:
            self.stopped = reason

    def check_stale(self, now: float) -> str | None:
        """Stop when the stream is stale at ``now``; the stop reason or None."""
        if self.stopped is None and self.frame_seen is not None:
            age = now - self.frame_seen
            if age > self.settings.stale_after:
                self.stop(f"target stream stale: no frame for {1e3 * age:.0f} ms "
                          f"(limit {1e3 * self.settings.stale_after:.0f} ms)")  # fmt: skip
        return self.stopped

    def setpoint(self, now: float) -> tuple[float, Array, Array, bool] | None:
        """The setpoint to send at ``now``: (its time t = now + lead, q, qd, laser_on), or
        None once stopped or before the first frame."""
        if self.check_stale(now) is not None or self.segment is None:
            return None
        st = self.settings
        t = now + st.lead
        dt = 1.0 / st.rate if self.t_last is None else max(t - self.t_last, 1e-6)
        q_ref, qd_ref = self.segment.q_ref(t)
        behind = self.segment.q_ref(t - dt)[0] - self.q  # the last setpoint's lag
        qd = qd_ref + behind / max(st.pull, dt)
        qd = np.clip(qd, -self._vmax, self._vmax)
        qd = np.clip(qd, self.qd - self._amax * dt, self.qd + self._amax * dt)
        qd = self._spot_speed_cap(qd, st.max_spot_speed, dt)
        q = np.clip(self.q + qd * dt, self._lower, self._upper)
        unsafe = self._violation(q)
        if unsafe is not None:
            self.stop(f"setpoint at t={t:.3f} s not sent: {unsafe}")
            self.unsafe = True
            return None
        self.qd = (q - self.q) / dt
        self.q, self.t_last = q, t
        lag = float(np.linalg.norm(self.segment.J @ (q - q_ref)))
        predicted = st.confidence * self.segment.sigma + lag + self.arm_gap
        return t, q.copy(), self.qd.copy(), bool(predicted <= st.tolerance)
