"""Closed-loop execution of point targets on the running system (no Zenoh here).

For each solved target, in the request's order, :class:`ClosedLoopRunner` servos the spot
(:func:`planner.servo.servo`) with a *measurement* as its basic act: a trajectory from where
the robots are to the commanded joints (Ruckig, timed and checked under the scenario's
safety rules like any plan, every beam off while moving), ending in a short dwell of
:func:`measure_time` s during which the *aiming* beam (``laser.aim``) is on and the
treatment gate off; once every robot rests on the commanded joints, the camera frames
captured in that dwell are averaged (confidence-weighted, mapped to the world with the
scenario's calibrated camera pose). The first measurement is the open-loop move to the
planned joints; each correction step is a small move of the same kind.

Aim, then treat: only when the servo ends ``converged`` - the last measured error within
the tolerance - does one more trajectory hold the final joints with the treatment gate on
for the dwell (the request's ``dwell``, else the scenario's ``trajectory.dwell``). A target
that ends ``not_improving``, ``max_iterations``, ``not_seen`` or ``refused`` is reported
and never treated (``treated: false``). The tolerance is the scenario's (the servo default);
a request may only tighten it. A gated system without ``laser.aim`` serves no closed loop
(``aim: gate`` for a rig whose only laser is a low-power diagnostic diode: its measurements
then switch the gate output as aim); an ungated one (simulation only) has its laser always
on.

Laser safety: the treatment beam is never on away from a target measured within tolerance;
the aiming beam of a measurement lands where the *uncorrected* spot lands, within the
calibration error of the target (a few mm), for :func:`measure_time` s (0.2 s at 3 frames);
the commanded beam of every measurement passes the same keep-out and clearance rules as a
planned dwell. A stop (``<prefix>/stop``) aborts at once: nothing more is sent (the drivers
brake and switch the laser off themselves), remaining targets are ``aborted``.
"""
# long module: the closed loop on the bus: moves, spot measurements, servo steps and its report share one run's state

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.beam.trace import trace_beam
from planner.errors import InputError
from planner.io.plan import Plan, Verdict
from planner.io.plan import Trajectory as PlanTrajectory
from planner.io.plan_reports import ClosedLoopReport, ClosedLoopTarget, FramesDropped, ServoFigures
from planner.model.settings import TrajectorySettings
from planner.model.status import Interruption, Status, evidence_text
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.service.execution import ExecuteError
from planner.service.spots import LaserLog, SpotBuffer
from planner.servo import (
    Corrector,
    ServoResult,
    ServoSettings,
    ServoStatus,
    average_frames,
    servo,
)
from planner.servo.measure import SpotGate, SpotMeasurement, gate_frames

if TYPE_CHECKING:
    from planner.service.handler import RequestHandler
    from planner.service.ports import ClosedLoopPort
    from schemas.messages import TargetRequest


#: camera frame period assumed for the measurement dwell (s; the D435 / sim camera at 30 Hz)
FRAME_PERIOD = 1.0 / 30.0
#: time after the robots come to rest before frames count (s): one frame exposed while moving
SETTLE = 0.04
#: how long (s) past a move's planned end the robots may take to rest on its final joints
ARRIVAL_TIMEOUT = 2.0
#: spot plausibility: least confidence of a frame that counts
MIN_CONFIDENCE = 0.3
#: m: a target's first spot must lie this close to the model's (the calibration error bound)
FIRST_RADIUS = 0.06
#: m: a later spot this close to the prediction (the model carried by the last measurement)
NEXT_RADIUS = 0.005
#: implausible frames in a row that stop the closed loop
MAX_IMPLAUSIBLE = 3
#: s between checks that the robots rest on a move's end / that a dwell is over
REST_POLL, HOLD_POLL = 0.004, 0.05

MoveFn = Callable[[Array, Array, float, Array, Array | None], PlanTrajectory]
"""(q_from, q_to stacked rad, dwell s, target world m, normal or None) -> the move's
:class:`~planner.io.plan.Trajectory` (laser on while dwelling); ExecuteError when no safe
move exists."""


def measure_time(frames: int) -> float:
    """Dwell (s) of a measurement of ``frames`` camera frames: the settle time plus one frame
    more than asked for (a frame straddling the start)."""
    return SETTLE + (frames + 1) * FRAME_PERIOD


def make_move_fn(system: System, settings: TrajectorySettings, safety: Any = None) -> MoveFn:
    """Timed moves for the closed loop through :func:`planner.plan.timed.time_safely` (the
    scenario's timing settings with the given dwell; the safety rules when given)."""
    from planner.ik.solve import Solution
    from planner.plan.timed import time_safely

    def move(q_from: Array, q_to: Array, dwell: float, target: Array,
             normal: Array | None) -> PlanTrajectory:  # fmt: skip
        tr = trace_beam(system, q_to, target, normal)
        sol = Solution.solved(np.asarray(q_to, dtype=float), tr, 0.0, 0, "servo")
        tg = Targets(np.asarray(target, dtype=float)[None],
                     None if normal is None else np.asarray(normal, dtype=float)[None])  # fmt: skip
        timed, sols, _, _ = time_safely(system, tg, [sol], replace(settings, dwell=dwell),
                                        safety=safety, order="given", path=None, progress=None,
                                        q_start=np.asarray(q_from, dtype=float))  # fmt: skip
        if timed is None or not sols[0].ok:
            why = sols[0].reason if sols and sols[0].reason else "no safe move"
            shown = evidence_text(sols[0].evidence) if sols else ""
            raise ExecuteError(f"closed-loop move refused: {why} ({shown})",
                               list(system.robot_names))  # fmt: skip
        return timed.trajectory.to_plan(system)

    return move


@dataclass(frozen=True)
class ClosedLoopConfig:
    """What a node needs for closed-loop requests: the corrector (calibrated model + safety
    rules), the move function, the scenario's dwell (s) and the servo's default settings."""

    corrector: Corrector
    move: MoveFn
    dwell: float
    settings: ServoSettings
    gated: bool = False
    """a robot's digital output switches the laser (``system.laser.gate``)"""
    aim: bool = False
    """measurements have an aiming beam (``system.laser.aim``, or ``aim: gate``)"""


def closed_loop_config(
    system: System, settings: TrajectorySettings, safety: Any = None, gated: bool = False,
    aim: bool = False,
) -> ClosedLoopConfig:  # fmt: skip
    """The closed-loop configuration of a scenario's system: its safety rules on every
    correction, its timing settings and dwell, the servo defaults, whether it is ``gated``
    and has an ``aim`` beam."""
    return ClosedLoopConfig(Corrector(system, safety), make_move_fn(system, settings, safety),
                            settings.dwell, ServoSettings(), gated, aim)  # fmt: skip


NO_AIM = ("closed_loop needs laser.aim: measurements use the aiming beam, never the treatment "
          "gate (aim: gate for a rig whose only laser is a low-power diagnostic diode)")  # fmt: skip


def check_closed_loop(
    req: TargetRequest, system: System, config: ClosedLoopConfig | None = None
) -> None:
    """InputError naming the field when a request's ``closed_loop`` cannot be served (with
    ``config``: no aiming beam, or a tolerance looser than the scenario's)."""
    if not req.closed_loop:
        return
    if config is not None and not config.aim:
        raise InputError(NO_AIM, "closed_loop")
    tol = getattr(req, "tolerance", None)
    if config is not None and tol is not None and tol > config.settings.tolerance:
        raise InputError(f"may only tighten the scenario's closed-loop tolerance "
                         f"{1e3 * config.settings.tolerance:g} mm, got {1e3 * tol:g} mm",
                         "tolerance")  # fmt: skip
    if not req.execute:
        raise InputError("closed_loop needs execute: true (the spot is measured on the "
                         "moving system)", "closed_loop")  # fmt: skip
    if req.mode != "points":
        raise InputError(f"closed_loop is for mode points, got mode {req.mode}", "closed_loop")
    if system.camera is None:
        raise InputError("closed_loop needs a camera in the scenario", "closed_loop")


@dataclass
class Motion:
    """The node's side of the runner: ``send(trajectory, id)`` -> (verdict, reason) of a
    move's :class:`~planner.io.plan.Trajectory`;
    ``rest_at(q)`` whether every robot rests on stacked ``q`` (rad); the spot buffer; the
    stop event; ``tick()`` reports progress to the worker's watchdog; ``laser`` the gate's
    on-intervals when a robot switches the laser (None: the laser is always on, frames count
    from the robots' arrival); ``predict(p_camera, t)`` publishes the predicted spot (camera
    frame, m; UNIX s) of each measurement for the camera's gated detector. ``clock`` (UNIX
    s, the clock of the frames and the laser's intervals) times every wait, and
    ``wait(s)`` waits at most ``s`` s, True once stopped (None: the stop event's wait)."""

    send: Callable[[PlanTrajectory, str], tuple[str, str | None]]
    rest_at: Callable[[Array], bool]
    spots: SpotBuffer
    stop: threading.Event
    tick: Callable[[], None]
    laser: LaserLog | None = None
    predict: Callable[[Array, float], None] | None = None
    clock: Callable[[], float] = time.time
    wait: Callable[[float], bool] | None = None

    def pause(self, seconds: float) -> bool:
        """Wait ``seconds`` s (or until a stop); whether a stop came."""
        return self.stop.wait(seconds) if self.wait is None else self.wait(seconds)


class ClosedLoopRunner:
    """Servo every solved target of one request (see the module docstring)."""

    def __init__(self, system: System, config: ClosedLoopConfig, motion: Motion,
                 request_id: str, settings: ServoSettings) -> None:  # fmt: skip
        self.system, self.config, self.motion = system, config, motion
        self.request_id, self.settings = request_id, settings
        self.q = system.home
        self.moves = 0
        self._target = np.zeros(3)
        self._normal: Array | None = None
        self.dropped = FramesDropped()  # frames gated out
        self._run = 0  # implausible frames in a row
        self._bias: Array | None = None  # last measured spot - model spot, this target

    def _send(self, q_to: Array, dwell: float, aim: bool = False) -> float:
        """Send one move to ``q_to`` with ``dwell`` (the aiming beam on in it with ``aim``,
        else the treatment gate) and wait until the robots rest there; the wall-clock time
        (UNIX s) they did. ExecuteError on a refusal."""
        traj = self.config.move(self.q, q_to, dwell, self._target, self._normal)
        if aim:
            traj = as_aim(traj)
        self.moves += 1
        verdict, reason = self.motion.send(traj, f"{self.request_id[:200]}.cl{self.moves}")
        if verdict != Verdict.ACCEPTED:
            raise ExecuteError(reason or "rejected", list(self.system.robot_names))
        self.q = np.asarray(q_to, dtype=float)
        clock = self.motion.clock
        deadline = clock() + float(traj.t[-1]) - dwell + ARRIVAL_TIMEOUT
        while not self.motion.stop.is_set():
            self.motion.tick()
            if self.motion.rest_at(self.q):
                return clock()
            if clock() > deadline:
                raise ExecuteError(f"the robots did not come to rest on the commanded joints "
                                   f"within {ARRIVAL_TIMEOUT:g} s of the move's end",
                                   list(self.system.robot_names))  # fmt: skip
            self.motion.pause(REST_POLL)
        return clock()

    def measure(self, q: Array, frames: int) -> SpotMeasurement | None:
        """Move to stacked ``q`` (rad) with a measurement dwell, average its frames: with a
        gated laser those captured while the gate was on for it (after ``SETTLE``), else
        those captured from the robots' arrival for the dwell."""
        t_dwell = measure_time(frames)
        predicted, gate = self._prediction(q)
        mo = self.motion
        t_send = mo.clock()
        t_rest = self._send(q, t_dwell, aim=True)
        stop = mo.stop.is_set
        t0, t1 = t_rest + SETTLE, t_rest + t_dwell
        if mo.laser is not None:
            span = mo.laser.wait_span(t_send, t_dwell + ARRIVAL_TIMEOUT, stop, clock=mo.clock,
                                      wait=mo.wait)  # fmt: skip
            if span is None:  # the gate never switched on for this measurement
                mo.tick()
                return None
            t0, t1 = span[0] + SETTLE, span[1]
        got = mo.spots.collect(t0, t1, frames, stop, clock=mo.clock, wait=mo.wait)
        self.motion.tick()
        assert self.system.camera is not None
        world_T_camera = self.system.world_T_camera(self.q)
        kept = self._gate(got, world_T_camera, predicted, gate)
        m = average_frames(kept, world_T_camera)
        if m is not None:
            self._bias = m.spot_world - self._model_spot(q)
        return m

    def _model_spot(self, q: Array) -> Array:

        return trace_beam(self.system, q, self._target, self._normal).spot

    def _prediction(self, q: Array) -> tuple[Array, SpotGate]:
        """Where the spot of a measurement at ``q`` should land (world, m) and the gate:
        the model's spot, moved by the last measurement's offset from the model once the
        target has one; published for the camera's detector."""
        pred = self._model_spot(q)
        radius = FIRST_RADIUS
        if self._bias is not None:
            pred, radius = pred + self._bias, NEXT_RADIUS
        if self.motion.predict is not None and self.system.camera is not None:
            camera_T_world = np.linalg.inv(self.system.world_T_camera(q))
            p_camera = camera_T_world[:3, :3] @ pred + camera_T_world[:3, 3]
            self.motion.predict(p_camera, self.motion.clock())
        return pred, SpotGate(MIN_CONFIDENCE, radius)

    def _gate(self, got: list[Any], world_T_camera: Array, predicted: Array,
              gate: SpotGate) -> list[Any]:  # fmt: skip
        """The frames that pass the plausibility gate; ExecuteError after
        :data:`MAX_IMPLAUSIBLE` implausible ones in a row."""
        kept, weak, far = gate_frames(got, world_T_camera, predicted, gate)
        self.dropped = FramesDropped(self.dropped.low_confidence + weak,
                                     self.dropped.implausible + far)  # fmt: skip
        self._run = 0 if any(f.p_camera is not None for f in kept) else self._run + far
        if self._run >= MAX_IMPLAUSIBLE:
            raise ExecuteError(f"{self._run} implausible spots in a row (each over "
                               f"{1e3 * gate.radius:g} mm from the predicted spot): the camera "
                               "sees something else; closed loop stopped",
                               list(self.system.robot_names))  # fmt: skip
        return kept

    def hold(self, dwell: float) -> float:
        """The laser-on dwell (s) at the current joints, counted from the robots' rest on
        the motion's clock; the dwell actually waited (s: less after a stop)."""
        if dwell <= 0:
            return 0.0
        clock = self.motion.clock
        t0 = self._send(self.q, dwell)
        end = t0 + dwell
        while (now := clock()) < end:
            if self.motion.pause(min(HOLD_POLL, end - now)):
                return min(clock() - t0, dwell)
            self.motion.tick()
        return dwell

    def target(self, k: int, q0: Array, p: Array, normal: Array | None,
               dwell: float) -> tuple[ServoResult, float]:  # fmt: skip
        """Servo target ``k`` (world, m) from its planned joints ``q0``, then dwell."""
        self._target, self._normal = np.asarray(p, dtype=float), normal
        self._bias = None
        res = servo(self.measure, q0, p, normal, self.config.corrector, self.settings,
                    should_stop=self.motion.stop.is_set)  # fmt: skip
        dwelt = 0.0
        if res.status is ServoStatus.CONVERGED:  # measured within tolerance: treat; else never
            dwelt = self.hold(dwell)
        return res, dwelt


def as_aim(trajectory: PlanTrajectory) -> PlanTrajectory:
    """A move's ``trajectory`` with its laser intervals given to the aiming beam
    (``aim_on``) and the treatment gate off throughout."""
    return replace(trajectory, aim_on=trajectory.laser_on, laser_on=trajectory.laser_on[:0])


def run_closed_loop(runner: ClosedLoopRunner, plan: Plan, targets: Targets,
                    start: Array, dwell: float) -> list[ClosedLoopTarget]:  # fmt: skip
    """Every target of ``plan`` in order; per target its row of the reply's
    ``closed_loop.targets``. A refused move ends the run (ExecuteError carries the rows so
    far in ``rows``)."""
    runner.q = np.asarray(start, dtype=float)
    rows: list[ClosedLoopTarget] = []
    for k, sol in enumerate(plan.solutions):
        target = int(plan.targets.ids[k])
        if runner.motion.stop.is_set():
            rows.append(ClosedLoopTarget(target, ServoStatus.ABORTED))
            continue
        if sol.status is not Status.OK:
            rows.append(ClosedLoopTarget(target, ServoStatus.NOT_PLANNED))
            continue
        q0 = runner.system.stack_q(dict(sol.q))
        try:
            res, dwelt = runner.target(k, q0, targets.points[k], targets.normal(k), dwell)
        except ExecuteError as exc:
            if runner.motion.stop.is_set():  # a stop made the drivers brake: not a refusal
                rows.append(ClosedLoopTarget(target, ServoStatus.ABORTED,
                                             reason=Interruption.STOP, detail=exc.reason))  # fmt: skip
                continue
            rows.append(ClosedLoopTarget(target, ServoStatus.REJECTED,
                                         reason=Interruption.EXECUTION, detail=exc.reason))  # fmt: skip
            exc.rows = rows  # type: ignore[attr-defined]
            raise
        rows.append(served_row(target, res, dwelt, runner.system.split_q(res.q)))
    return rows


def served_row(target: int, res: ServoResult, dwelt: float,
               q: Mapping[str, Array]) -> ClosedLoopTarget:  # fmt: skip
    """The row of a servoed target: its servo result, the treatment dwell held (s) and the
    joints the arms were left at (rad per robot)."""

    def num(x: float) -> float | None:
        return None if not np.isfinite(x) else float(x)

    figures = ServoFigures(
        res.iterations, res.frames, float(res.time), num(res.error_before), num(res.error_after),
        np.asarray(res.errors, dtype=float).reshape(-1),
        None if res.spot is None else np.asarray(res.spot, dtype=float),
        {robot: np.asarray(x, dtype=float) for robot, x in q.items()},
    )  # fmt: skip
    failure = res.failure
    return ClosedLoopTarget(target, res.status, dwelt, dwelt > 0, figures,
                            None if failure is None else failure.reason,
                            None if failure is None else failure.detail)  # fmt: skip


def closed_loop_figures(rows: Sequence[ClosedLoopTarget]) -> dict[str, float]:
    """``metrics.extra`` figures of a closed-loop run (m, s): the measured error after and
    before the servo (median, max over the targets measured), targets converged, frames,
    iterations and servo time (max; median time)."""
    served = [r.servo for r in rows if r.servo is not None]
    after = [s.error_after for s in served if s.error_after is not None]
    before = [s.error_before for s in served if s.error_before is not None]
    out: dict[str, float] = {
        "closed_loop_converged": float(sum(r.converged for r in rows)),
        "closed_loop_targets": float(len(rows)),
    }
    if after:
        out |= {"measured_error_median": float(np.median(after)),
                "measured_error_max": float(np.max(after))}  # fmt: skip
    if before:
        out |= {"measured_error_before_median": float(np.median(before)),
                "measured_error_before_max": float(np.max(before))}  # fmt: skip
    if served:
        out |= {"closed_loop_frames_max": float(max(s.frames for s in served)),
                "closed_loop_iterations_max": float(max(s.iterations for s in served)),
                "closed_loop_time_median": float(np.median([s.time for s in served])),
                "closed_loop_time_max": float(max(s.time for s in served))}  # fmt: skip
    return out


def in_camera_frame(rows: Sequence[ClosedLoopTarget], targets_camera: Array,
                    world_T_camera: Array) -> list[ClosedLoopTarget]:  # fmt: skip
    """The rows of a camera-frame request with their target and last measured spot as the
    camera sees them (``target_camera``, ``spot_camera``, m, optical frame) and
    ``error_camera`` (m). ``world_T_camera`` is the calibrated camera pose the request's
    points were mapped to the world with (at the request's start joints); a fixed camera's
    spots were mapped with the same one, so its extrinsic error drops out of the difference
    the servo drove to zero."""
    camera_T_world = np.linalg.inv(world_T_camera)
    out = list(rows)
    for k, (row, p_c) in enumerate(zip(rows, targets_camera, strict=False)):
        p_c = np.asarray(p_c, dtype=float)
        spot = None if row.servo is None else row.servo.spot
        if spot is None:
            out[k] = replace(row, target_camera=p_c)
            continue
        s_c = camera_T_world[:3, :3] @ spot + camera_T_world[:3, 3]
        out[k] = replace(row, target_camera=p_c, spot_camera=s_c,
                         error_camera=float(np.linalg.norm(s_c - p_c)))  # fmt: skip
    return out


def execute_closed_loop(plan: Plan, targets: Targets, req: TargetRequest, start: Array,
                        config: ClosedLoopConfig, motion: Motion, system: System) -> Plan:  # fmt: skip
    """Run a closed-loop request's targets from stacked ``start`` (rad); the plan with the
    reply's ``closed_loop`` (:class:`~planner.io.plan_reports.ClosedLoopReport`),
    ``metrics.extra`` (:func:`closed_loop_figures`), ``execution`` and
    ``execution_reason``."""
    if not plan.any_ok:
        raise ExecuteError("no target could be solved, nothing to execute", [])
    settings = config.settings
    if req.tolerance is not None:
        settings = replace(settings, tolerance=float(req.tolerance))
    dwell = config.dwell if req.dwell is None else float(req.dwell)
    runner = ClosedLoopRunner(system, config, motion, req.id, settings)
    verdict, reason = Verdict.ACCEPTED, None
    try:
        rows = run_closed_loop(runner, plan, targets, start, dwell)
    except ExecuteError as exc:
        rows = list(getattr(exc, "rows", []))
        k = len(rows) - 1
        rows += [ClosedLoopTarget(int(i), ServoStatus.NOT_EXECUTED, treated=None)
                 for i in plan.targets.ids[len(rows):]]  # fmt: skip
        verdict, reason = Verdict.REJECTED, f"target {k}: {exc.reason}"
    if motion.stop.is_set():
        reason = "closed loop aborted: a stop was seen on the bus"
    if req.frame == "camera":
        rows = in_camera_frame(
            rows, np.asarray(req.points, dtype=float), system.world_T_camera(start)
        )
    report = ClosedLoopReport(settings.tolerance, settings.frames, dwell, runner.moves,
                              runner.dropped, req.frame, tuple(rows))  # fmt: skip
    return replace(
        plan,
        closed_loop=report,
        execution=verdict,
        execution_reason=reason,
        metrics=plan.metrics.with_extra(**closed_loop_figures(rows)),
    )


def execute_on_node(node: ClosedLoopPort, plan: Plan, targets: Targets, req: TargetRequest,
                    start: dict[str, Array], handler: RequestHandler) -> Plan:  # fmt: skip
    """:func:`execute_closed_loop` on a :class:`planner.service.node.PlannerNode`: from
    ``start`` (rad per robot), in the calibration of ``handler`` (the one the request was
    planned with), moving through the node's execution, measuring with its spot buffer (and
    laser log when the laser is gated), aborted by a stop seen on the bus. With online
    calibration, the measurement dwells at rest are its samples (the rest sampler)."""
    config = handler.closed_loop
    assert config is not None
    system = handler.system

    def send(trajectory: PlanTrajectory, move_id: str) -> tuple[str, str | None]:
        sent = node.execution.execute(replace(plan, trajectory=trajectory), move_id,
                                      node.session_id)  # fmt: skip
        return str(sent.execution), sent.execution_reason

    def rest_at(q: Array) -> bool:
        return bool(node.joints.rests_at(system.split_q(q)))

    node.stop_seen.clear()
    laser = node.laser if config.gated else None
    predicted_key = f"{node.keys.prefix}/camera/predicted"

    def predict(p_camera: Array, t: float) -> None:  # the camera's gated detector looks there
        body = {"schema": "beamrelay.predicted/1", "p_camera": [float(x) for x in p_camera], "t": t}
        node.session.put(predicted_key, json.dumps(body).encode(), encoding="application/json")

    motion = Motion(send, rest_at, node.spots, node.stop_seen, node.progress.tick, laser,
                    predict)  # fmt: skip
    return execute_closed_loop(plan, targets, req, system.stack_q(start), config, motion, system)
