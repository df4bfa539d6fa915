"""The Zenoh side of a robot driver, common to the ``sim`` and ``ur`` backends.

:class:`RobotNode` runs the backend's control loop in a thread (one
:meth:`RobotBackend.step` per period, 500 Hz by default). Every command to the arm is
given from that thread; the Zenoh callbacks only record what they received.

Bus (``<prefix>`` = the namespace, ``beamrelay`` by default):

- publishes ``<prefix>/<robot>/joint_states`` (:class:`schemas.messages.JointState`, rad,
  rad/s, ``t`` = UNIX time) every ``rate / state_rate`` periods (250 Hz by default) and
  ``<prefix>/<robot>/status`` (:class:`schemas.messages.RobotStatus`) on every mode change,
  at 10 Hz and at once for every trajectory received: ``trajectory`` is the verdict
  (:class:`schemas.messages.TrajectoryAck`: request ``id``, accepted, reason), repeated in
  every later status until the next trajectory;
- subscribes ``<prefix>/<robot>/trajectory``: bodies are parsed and checked in a worker
  process (:mod:`drivers.robot.intake`, checks in :mod:`drivers.robot.trajectory_check`); the loop picks
  up ready verdicts without waiting;
- subscribes ``<prefix>/<robot>/setpoint`` (:class:`schemas.messages.Setpoint`): queued by
  Zenoh's threads without the GIL (like the heartbeats, below), parsed and checked at the
  start of the next period (:mod:`drivers.robot.setpoint_intake`), followed by the
  loop (:mod:`drivers.robot.streaming`, rules below); the status's ``stream``
  (:class:`schemas.messages.StreamAck`) says which stream is followed or why it ended;
- subscribes ``<prefix>/heartbeat`` (:class:`schemas.messages.Heartbeat`) and
  ``<prefix>/stop``, declares ``<prefix>/alive/<robot>`` and watches ``<prefix>/alive/planner``;
- with a laser gate (``gate_output``: this robot's digital output switches the laser):
  publishes ``<prefix>/laser`` (:class:`schemas.messages.LaserState`) at every switch and
  with every status; the status carries ``laser_on``;
- with ``chain`` (the other robots of the beam chain, on the gate's driver): subscribes their
  ``status``, ``joint_states`` and ``<prefix>/alive/<robot>`` (:mod:`drivers.robot.chain`);
  a laser interval played while one of them is not live and following switches treatment
  off, safety-stops this arm and publishes ``<prefix>/stop`` so every arm stops.

Laser gate: switched in the control loop, in the period that plays the trajectory's
``laser_on`` intervals (:meth:`drivers.robot.follower.Reference.laser_edge`) or while a
followed setpoint stream's newest setpoint says ``laser_on``, by the
backend's ``set_gate`` (sim: recorded; UR: ``setStandardDigitalOut``). It is off at start-up,
outside ``following`` and ``streaming``, on a backend fault, and forced off
first thing in every safety stop and at exit (:class:`drivers.robot.gate.LaserGate`, which
records each switch: its lag behind the interval's edge in trajectory time and its latency
from the period's start). A trajectory with ``laser_on`` sent to a driver without a gate is refused.

Acceptance, decided in the control loop when the worker's verdict arrives:

1. the state-free checks passed (names, limits, no position jumps, declared derivatives
   consistent with the positions);
2. with ``require_planner`` (the default): a planner token is alive and a heartbeat from the
   trajectory's ``session`` arrived within :data:`HEARTBEAT_TIMEOUT` (a trajectory without
   a session is refused);
3. it was received after the last stop request, and the arm is not braking;
4. start: while a trajectory executes (approach, following, settle), the new one must start
   within ``start_tolerance`` of the running one's *last* sample: it is queued and starts
   when the running one reaches that sample (the planner plans from the state the arm will
   be in then). At most one is queued; a newer one replaces it (the replaced one never
   runs and gets no second verdict). With the arm at rest it must start within
   ``start_tolerance`` of the measured joints and starts at once.

Setpoint streams (a stream = the setpoints of one (session, id); the intake rejects a
setpoint that breaks a limit against the previous one, which ends the stream):

1. a stream starts with its first setpoint if rules 2 and 3 above hold for its session, the
   arm executes no trajectory, the first setpoint lies within 0.01 rad and 0.1 rad/s of the
   measured state (:func:`drivers.robot.setpoint_check.check_stream_start`), and
   ``laser_on`` is only asked of the gating robot; else it is refused (the status says why)
   and its later setpoints are ignored until they pause for 50 ms;
2. it ends when no setpoint came for 50 ms (receive clock): the laser goes off; an arm at
   rest on the last setpoint stays there (``idle``), a moving one brakes; on a rejected
   setpoint, a stop, a heartbeat loss or a fault (a safety stop); or when a trajectory is
   accepted, which then approaches from the moving state.

Safety stops (:meth:`RobotNode._safe_stop`, the one place every stop goes through: brake
with the stop deceleration of :mod:`drivers.robot.follower`, drop the queued trajectory):

- heartbeat: while the arm executes a trajectory or follows a stream with
  ``require_planner``, the sessions of the running and the queued trajectory and of the
  stream must each have sent a heartbeat within
  :data:`HEARTBEAT_TIMEOUT` (0.1 s), checked every period; heartbeats of other sessions do
  not count. Beats are queued by Zenoh's own (Rust) threads in a ring of
  :data:`HEARTBEAT_RING` without Python's GIL and taken by the control loop at the start of
  every period: a Python thread of this process that holds the GIL while the machine is
  busy can delay the loop, but no beat that reached the process counts as missing once the
  loop runs (a Python callback would wait for the GIL behind the loop and the beat would
  look late: a false brake). A beat counts from the period that took it, but never more
  than :data:`HEARTBEAT_TIMEOUT` after it was sent (its ``t`` on this clock: plus the
  smallest receive-minus-send offset its session has shown), so a planner that hangs while
  the loop stalls brakes the arm at most 200 ms after its last beat. A flood of beats beyond the ring drops the oldest, so a real
  beat can be pushed out: the arm then brakes (fail-safe); at most
  :data:`BEATS_PER_PERIOD` are decoded per period;
- the planner's liveliness token disappearing (an extra trigger: it comes 2-9 ms after the
  planner process dies, but a hung planner keeps it for the ~9 s Zenoh lease);
- any sample on ``<prefix>/stop``, whatever its body: brake, and refuse every trajectory
  received before the stop (also those still being parsed); the first trajectory received
  after it, once the arm is at rest, is judged by the rules above.
"""
# long module: the robot driver's rules (admission, heartbeat watchdog, stop, laser gate, status) act on one node's state

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import numpy as np

from drivers.loop_node import LoopNode
from drivers.robot.backend import Measured, RobotBackend
from drivers.robot.chain import ChainWatch
from drivers.robot.follower import REST_VELOCITY, Reference
from drivers.robot.gate import Emission, LaserGate
from drivers.robot.intake import TrajectoryIntake, Verdict
from drivers.robot.node_streams import EXECUTING, StreamingMixin
from drivers.robot.setpoint_intake import SetpointIntake
from drivers.robot.streaming import StreamControl
from drivers.robot.trajectory_check import START_TOLERANCE, check_start
from drivers.robot.trajectory_check import check_trajectory as check_trajectory
from drivers.robot.ur_link import RateLimitedLog, recover_key
from planner.bus.events import event, stop_fields
from planner.bus.ids import base_id
from planner.bus.priority import Priority, raise_priority
from planner.bus.session import JSON, Keys, decode, encode, urgent
from planner.errors import InputError
from planner.model.system import Limits
from schemas.brakes import Brake
from schemas.messages import (
    Heartbeat,
    JointState,
    RobotStatus,
    StopMessage,
    TrajectoryAck,
    parse_recover,
)

log = logging.getLogger("beamrelay.driver")
HEARTBEAT_TIMEOUT = 0.100  # s: longest planner silence before the arm brakes
#: s: a setpoint stream this silent is late: treatment off until the next setpoint (three
#: periods of a 500 Hz stream; the stream itself ends at 50 ms)
LATE_SETPOINT = 0.006
MAX_SESSIONS = 64  # heartbeat sessions remembered (oldest forgotten first)
#: heartbeats queued between two periods (at 100 Hz per planner: 2.5 s of one planner's
#: beats; beyond it the oldest are dropped, never blocking Zenoh's receive thread)
HEARTBEAT_RING = 256
BEATS_PER_PERIOD = 32  # beats decoded per period at most (a flood cannot stretch a period)
#: setpoints queued between two periods (0.5 s of a 500 Hz stream), of which the loop parses
#: at most SETPOINTS_PER_PERIOD per period (a flood cannot stretch a period; the rest wait)
SETPOINT_RING = 256
SETPOINTS_PER_PERIOD = 16
RT_IDLE = 0.0002  # s a real-time control loop sleeps after a period that did not sleep
PERIOD_LOG = 1 << 16  # control periods whose start times are kept (2 min at 500 Hz)


def queued(ring: Any, at_most: int) -> Iterator[Any]:
    """Up to ``at_most`` samples waiting in a Zenoh channel subscriber ``ring`` (none when
    it is None: not attached), oldest first, without blocking."""
    for _ in range(at_most if ring is not None else 0):
        sample = ring.try_recv()
        if sample is None:
            return
        yield sample


class Accepted(NamedTuple):
    """A trajectory handed to the backend, with the planner session it answers to."""

    id: str | None
    session: str | None
    reference: Reference


class RobotNode(StreamingMixin, LoopNode):
    """Runs one backend on the bus (see the module docstring)."""

    # long: the driver node's 15 keyword settings and its state are assigned in one place; no logic
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
        gate_output: int | None = None,
        emission: Emission | None = None,
        chain: tuple[str, ...] = (),
        clock: Callable[[], float] = time.monotonic,
        realtime: bool = False,
    ) -> None:
        super().__init__()
        self.realtime = realtime  # the control loop thread asks for SCHED_FIFO
        self.loop_priority: Priority | None = None  # what it obtained (None: not asked)
        self.clock = clock  # monotonic s: every receive time and period start
        if emission is None and gate_output is not None:
            emission = Emission(gate_output)
        self.emission = emission  # the laser outputs' rules (None: this driver has none)
        self.gate_output = None if emission is None else emission.gate_output
        self.gate: LaserGate | None = None  # made in start() (it publishes)
        self.chain = ChainWatch(tuple(r for r in chain if r != robot), clock)
        self._playing_since: float | None = None  # monotonic s: this arm plays since
        self.session = session
        self.keys = keys
        self.robot = robot
        self.backend = backend
        self.limits = limits
        self.start_tolerance = start_tolerance
        self.require_planner = require_planner
        self._state_every = max(1, round(backend.rate / state_rate))
        self._status_every = max(1, round(backend.rate / status_rate))
        self.intake = TrajectoryIntake(robot, backend.names, limits, 1.0 / backend.rate)
        self.setpoints = SetpointIntake(robot, backend.names, limits, clock=clock)
        self.streams = StreamControl(limits, 1.0 / backend.rate)
        self.heartbeats: dict[str, float] = {}  # session -> monotonic time of its last beat
        self._beats: Any = None  # the heartbeat subscriber's ring (made in attach)
        self._beat_offsets: dict[str, float] = {}  # session -> min(receive - send) (s)
        self._setpoint_ring: Any = None  # the setpoint subscriber's ring (made in attach)
        self.planner_alive = False
        self.planner_lost_at: float | None = None  # UNIX time the planner's token went away
        self.stop_requested_at: float | None = None  # monotonic time of the last stop sample
        self.stopped_by: str | None = None  # why the last safety stop happened
        self.rejection: str | None = None
        self.ack: TrajectoryAck | None = None
        self.n_accepted = 0
        self.n_rejected = 0
        self.n_bad_heartbeats = 0
        self.period_starts = np.zeros(PERIOD_LOG)  # monotonic s, ring buffer
        self.n_periods = 0
        self._running: Accepted | None = None
        self._queued: Accepted | None = None
        self._triggers: list[str] = []  # stop reasons from callbacks, for the loop
        self._handled_stop: float | None = None
        self.recover_requested = False
        self.recover_log = RateLimitedLog(robot)
        self._tick = 0
        self._last_mode: tuple[str, bool, bool] = ("", False, False)

    # -- lifecycle ---------------------------------------------------------------------
    def start(self) -> RobotNode:
        """Start the parse worker, declare everything on the bus, run the control loop."""
        self.intake.start()
        self.attach()
        self._start_loop(f"{self.robot}-control")
        return self

    def attach(self) -> RobotNode:
        """Declare publishers, subscribers and the token (no thread: tests then drive
        :meth:`period` themselves)."""
        import zenoh

        s, k = self.session, self.keys
        self._beats = s.declare_subscriber(k.heartbeat, zenoh.handlers.RingChannel(HEARTBEAT_RING))
        self._setpoint_ring = s.declare_subscriber(
            k.setpoint(self.robot), zenoh.handlers.RingChannel(SETPOINT_RING)
        )
        self._pub_state = s.declare_publisher(k.joint_states(self.robot), encoding=JSON)
        self._pub_status = s.declare_publisher(k.status(self.robot), encoding=JSON)
        if self.gate_output is not None:
            pub = s.declare_publisher(k.laser, encoding=JSON)
            assert self.emission is not None
            self.gate = LaserGate(self.robot, self.emission, self.backend, pub.put, self.clock)
            self.gate.force_off("start-up")
        self._handles = [
            s.declare_subscriber(k.trajectory(self.robot), self._on_trajectory),
            self._setpoint_ring,
            self._beats,
            s.declare_subscriber(k.stop, self._on_stop),
            s.liveliness().declare_subscriber(k.alive("planner"), self._on_planner, history=True),
            s.declare_subscriber(recover_key(k.prefix, self.robot), self._on_recover),
            s.liveliness().declare_token(k.alive(self.robot)),
        ]
        self._pub_stop = s.declare_publisher(k.stop, **urgent()) if self.chain.robots else None
        for r in self.chain.robots:
            self._handles += [
                s.declare_subscriber(k.status(r), self.chain.on_status(r)),
                s.declare_subscriber(k.joint_states(r), self.chain.on_state(r)),
                s.liveliness().declare_subscriber(k.alive(r), self.chain.on_alive(r), history=True),
            ]
        return self

    def _close(self) -> None:
        """Laser off, stop the arm (backend ``close``) and the parse worker."""
        if self.gate is not None:
            self.gate.force_off("driver exit")
        self.backend.close()
        self.intake.close()

    # -- callbacks (Zenoh threads): record, never command ------------------------------------
    def _on_planner(self, sample: Any) -> None:
        import zenoh

        alive = sample.kind == zenoh.SampleKind.PUT
        self.planner_alive = alive
        if not alive:
            self.planner_lost_at = time.time()
            self._triggers.append("planner liveliness lost")

    def _take_heartbeats(self, now: float) -> None:
        """The beats queued since the last period (at most :data:`BEATS_PER_PERIOD`), each
        heard now but at most HEARTBEAT_TIMEOUT past its sending (:meth:`_on_heartbeat`)."""
        for sample in queued(self._beats, BEATS_PER_PERIOD):
            self._on_heartbeat(sample, now)

    def _on_heartbeat(self, sample: Any, now: float) -> None:
        try:
            if len(sample.payload) > 4096:
                raise InputError("heartbeat body over 4096 bytes", "body")
            beat = decode(sample.payload.to_bytes(), Heartbeat)
        except Exception:  # a bad heartbeat is no heartbeat
            self.n_bad_heartbeats += 1
            return
        # heard when taken (``now``), but never later than HEARTBEAT_TIMEOUT after it was
        # sent on this clock (its ``t`` plus the smallest receive - send offset its session
        # has shown): a beat that waited in this process (the GIL, a stalled loop) is not
        # late for it, yet a planner that hung while the loop stalled is silent at most
        # 2 x HEARTBEAT_TIMEOUT after its last beat; a stamp from the future only lowers
        # the offset (the session's later beats look older, never fresher)
        offsets, beats = self._beat_offsets, self.heartbeats
        offset = min(offsets.get(beat.session, np.inf), now - beat.t)
        heard = min(now, beat.t + offset + HEARTBEAT_TIMEOUT)
        if beat.session not in beats and len(beats) >= MAX_SESSIONS:
            oldest = min(beats, key=beats.__getitem__)  # forget the longest silent
            del beats[oldest]
            offsets.pop(oldest, None)
        offsets[beat.session] = offset
        beats[beat.session] = max(beats.get(beat.session, -np.inf), heard)

    def _on_stop(self, sample: Any) -> None:
        self.stop_requested_at = self.clock()
        event(log, "stop_seen", logging.WARNING, robot=self.robot, **stop_fields(sample))

    def _on_trajectory(self, sample: Any) -> None:
        self.intake.submit(sample.payload)

    def _drop_queued_setpoints(self) -> None:
        """Discard the setpoints Zenoh queued since the last period (a stop came meanwhile:
        they may have been sent before it and must not start a stream after it)."""
        for _ in queued(self._setpoint_ring, SETPOINT_RING):
            pass

    def _take_setpoints(self) -> None:
        """Setpoints queued since the last period (at most :data:`SETPOINTS_PER_PERIOD`),
        parsed and checked here, received at this period's start."""
        for sample in queued(self._setpoint_ring, SETPOINTS_PER_PERIOD):
            self.setpoints.submit(sample.payload)

    def _on_recover(self, sample: Any) -> None:
        """The operator's acknowledgement after a fault (``beamrelay robot recover``)."""
        try:
            parse_recover(sample.payload.to_bytes(), self.robot)
        except (ValueError, UnicodeDecodeError) as exc:
            self.recover_log(f"ignored a bad recover request: {exc}")
            return
        self.recover_requested = True

    # -- control loop --------------------------------------------------------------------
    def _loop(self) -> None:
        """Periods until stopped. With ``realtime`` the thread runs under SCHED_FIFO where
        permitted (what it starts later begins normal); a period that overran its ``dt``
        (the backend did not sleep) then sleeps :data:`RT_IDLE` s, so a late loop never holds
        a core."""
        dt = 1.0 / self.backend.rate
        if self.realtime:
            self.loop_priority = raise_priority(reset_on_fork=True)
            print(f"{self.robot}: control loop {self.loop_priority.note}", file=sys.stderr)
        while not self._stop.is_set():
            t0 = time.monotonic()
            self.period()
            if self.realtime and time.monotonic() - t0 >= dt:
                time.sleep(RT_IDLE)

    def period(self) -> None:
        """One control period: stop triggers, verdicts, streams, one backend step, gate,
        states and status (the backend paces it)."""
        self.backend.begin_period()
        now = self.clock()
        self.period_starts[self.n_periods % PERIOD_LOG] = now
        if self.gate is not None:
            self.gate.period_start = now
        self.n_periods += 1
        self._watch(now)
        for verdict in self.intake.take():
            self._decide(verdict)
            self._publish_status(self.backend.measured())
        self._take_setpoints()
        self._follow_streams(now)
        if self.recover_requested:
            self.recover_requested = False
            recover = getattr(self.backend, "recover", None)
            self.recover_log(recover() if recover else "recover: nothing to do (sim)")
            if self.gate is not None and self.gate.fault is not None:
                self.recover_log(self.gate.recover(self.backend.measured()))
        m = self.backend.step()
        self._track()
        if self.streams.active is not None and m.mode != "streaming":
            self._safe_stop(f"arm left the stream: {m.fault or m.mode}")
        if self.gate is not None:
            silent = self.streams.silent(now)
            fresh = silent <= LATE_SETPOINT  # treatment only on time
            late = None if fresh else f"late setpoint: none for {1e3 * silent:.0f} ms"
            chain = self._chain_fault()
            abort = self.gate.update(m, m.fault, self.streams.laser_on and fresh,
                                     self.streams.aim, chain, late)  # fmt: skip
            if abort is not None:
                self._safe_stop(abort)
                if chain is not None and abort.endswith(chain):
                    self._stop_all(abort)
        if self._tick % self._state_every == 0 and not m.stale:
            state = JointState(
                t=time.time(), names=list(self.backend.names), q=m.q.tolist(), qd=m.qd.tolist()
            )
            self._pub_state.put(encode(state))
        mode = (m.mode, m.protective_stop, m.fault is not None)  # a change: published at once
        if mode != self._last_mode or self._tick % self._status_every == 0:
            self._publish_status(m)
            self._last_mode = mode
        self._tick += 1
        self.backend.end_period()

    def _watch(self, now: float) -> None:
        """Stop triggers, once per period: stop requests, token loss, silent heartbeats."""
        self._take_heartbeats(now)
        stop_at = self.stop_requested_at
        if stop_at is not None and stop_at != self._handled_stop:
            self._handled_stop = stop_at
            self._drop_queued_setpoints()  # sent before the stop, maybe: never a new stream
            self._safe_stop(Brake.OPERATOR_STOP.say(f" {self.keys.stop}"))
        while self._triggers:
            self._safe_stop(self._triggers.pop(0))
        if not self.require_planner:
            return
        sessions = [self.streams.active.session] if self.streams.active is not None else []
        if self.backend.follower.mode in EXECUTING:
            sessions += [a.session for a in (self._running, self._queued) if a and a.session]
        for session in sessions:
            silent = now - self.heartbeats.get(session, -np.inf)
            if silent > HEARTBEAT_TIMEOUT:
                quiet = "none heard" if np.isinf(silent) else f"silent for {1e3 * silent:.0f} ms"
                self._safe_stop(Brake.HEARTBEAT_LOST.say(f": session {session} {quiet}"))
                return

    def _safe_stop(self, reason: str, rejected: str | None = None) -> None:
        """Every safety stop goes through here: laser gate off, end the stream (``rejected``:
        the setpoint's reason), brake with the stop deceleration, drop the queued
        trajectory, and say why in the status."""
        if self.gate is not None:
            self.gate.force_off(reason)
        moving = bool(np.any(np.abs(self.backend.follower.qd) > REST_VELOCITY))
        active = self.streams.active
        running = self._running.id if self._running is not None else None
        running = running if active is None else active.id
        stream = self.streams.end(rejected or reason, moving, rejected is not None)
        if stream is not None:
            self.setpoints.end(stream)
        self.backend.brake(reason)
        event(log, "stop", logging.WARNING, robot=self.robot, id=running, reason=reason)
        self._running = self._queued = None
        self.stopped_by = reason

    def _chain_fault(self) -> str | None:
        """Why an arm of the beam chain is not live and following (None: all are)."""
        if not self.chain.robots:
            return None
        now, playing = self.clock(), self.backend.follower.mode in (*EXECUTING, "streaming")
        if not playing:
            self._playing_since = None
        elif self._playing_since is None:
            self._playing_since = now
        running = self._running.id if self._running is not None else None
        return self.chain.fault(now, base_id(running), self._playing_since)

    def _stop_all(self, reason: str) -> None:
        """Publish ``<prefix>/stop``: every arm brakes (the beam left the chain)."""
        if self._pub_stop is not None:
            msg = StopMessage(t=time.time(), source=self.robot, reason=reason[:1000])
            self._pub_stop.put(encode(msg), encoding=JSON)

    def _track(self) -> None:
        """Follow the backend: the queued trajectory started, or everything ended."""
        f = self.backend.follower
        if self._queued is not None and f.reference is self._queued.reference:
            self._running, self._queued = self._queued, None
        elif f.reference is None:
            self._running = self._queued = None

    def _decide(self, v: Verdict) -> None:
        """Accept (start or queue) or reject one checked trajectory; record the verdict."""
        try:
            if v.reference is None:
                raise InputError(v.reason or "rejected", "")
            self._check_emission(v.reference.laser_on is not None, v.reference.aim_on is not None)
            self._admissible(v.received, v.session)
            acc = Accepted(v.id, v.session, v.reference)
            if self.backend.follower.mode in EXECUTING and self._running is not None:
                last = self._running.reference.q[-1]
                check_start(acc.reference.q[0], last, self.backend.names, self.start_tolerance,
                            "the running trajectory's last sample")  # fmt: skip
                self.backend.queue(acc.reference)
                self._queued = acc
            else:
                check_start(acc.reference.q[0], self.backend.measured().q, self.backend.names,
                            self.start_tolerance, "the current state")  # fmt: skip
                self.backend.command(acc.reference)
                self._running, self._queued = acc, None
                if self.streams.active is not None:
                    self._end_stream(f"replaced by trajectory {v.id}")
        except InputError as exc:
            self.n_rejected += 1
            self.rejection = f"trajectory rejected: {exc}"
            self.ack = TrajectoryAck(id=v.id, accepted=False, reason=str(exc), t=time.time())
            event(log, "rejected", logging.WARNING, robot=self.robot, id=v.id, reason=str(exc))
            return
        self.n_accepted += 1
        self.rejection = self.stopped_by = None
        self.ack = TrajectoryAck(id=v.id, accepted=True, t=time.time())
        event(log, "accepted", robot=self.robot, id=v.id)

    def _check_emission(self, laser_on: bool, aim_on: bool) -> None:
        """InputError when a trajectory or stream asks for a laser this driver cannot (or,
        after a latched fault or the session's energy, may not) switch."""
        if laser_on and self.gate is None:
            raise InputError("laser_on given, but this driver switches no laser gate "
                             "(laser.gate names another robot, or none)", "laser_on")  # fmt: skip
        if aim_on and (self.emission is None or self.emission.aim_output is None):
            raise InputError("aim_on given, but this driver switches no aiming beam "
                             "(laser.aim names another robot, or none)", "aim_on")  # fmt: skip
        gate = self.gate
        if laser_on and gate is not None and (gate.fault or gate.spent):
            raise InputError(f"the laser is locked out: {gate.fault or gate.spent}", "laser_on")
        aim_is_gate = self.emission is not None and self.emission.aim_output == self.gate_output
        if aim_on and aim_is_gate and gate is not None and (gate.fault or gate.spent):
            raise InputError(f"the laser is locked out: {gate.fault or gate.spent}", "aim_on")

    def _admissible(self, received: float, session: str | None) -> None:
        """Rules 2 and 3 of the module docstring (InputError if not)."""
        stop_at = self.stop_requested_at
        if stop_at is not None and received <= stop_at:
            raise InputError(Brake.SENT_BEFORE_STOP.say(f" {self.keys.stop}"), "body")
        if self.backend.follower.mode == "braking":
            raise InputError("the arm is braking: send it once the arm is at rest", "body")
        if not self.require_planner:
            return
        if not self.planner_alive:
            raise InputError(Brake.NO_PLANNER.say(": not moving"), "body")
        if session is None:
            raise InputError("no planner session given (a planner must send it)", "session")
        silent = self.clock() - self.heartbeats.get(session, -np.inf)
        if silent > HEARTBEAT_TIMEOUT:
            heard = "never" if np.isinf(silent) else f"{1e3 * silent:.0f} ms ago"
            raise InputError(
                Brake.SESSION_SILENT.say(
                    f" {session} within {1e3 * HEARTBEAT_TIMEOUT:.0f} ms (last: {heard})"
                ),
                "session",
            )

    def _publish_status(self, m: Measured) -> None:
        gate_fault = self.gate.fault if self.gate is not None else None
        fault = m.fault or gate_fault or self.rejection or self.stopped_by
        if fault is None and not self.planner_alive and self.require_planner:
            fault = Brake.NO_PLANNER.value
        laser = self.gate.on if self.gate is not None else None
        msg = RobotStatus(
            robot=self.robot, t=time.time(), mode=m.mode, protective_stop=m.protective_stop,
            fault=fault, trajectory=self.ack, stream=self.streams.status(), laser_on=laser,
            safety_mode=m.safety,
        )  # fmt: skip
        self._pub_status.put(encode(msg))
        if self.gate is not None:
            self.gate.publish()
