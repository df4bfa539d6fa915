"""Starting a ``mode: track`` request: the first estimate's plan, the planned approach to it,
then a :class:`planner.service.track.TrackSession` following the target stream."""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.errors import InputError
from planner.io.plan import Plan, Verdict
from planner.io.plan_reports import TrackingReport
from planner.model.status import Status
from planner.model.system import Targets
from planner.model.transforms import Array
from planner.service.execution import ExecuteError
from planner.service.track import TrackSession
from planner.track.correction import SpotCorrection
from planner.track.follow import TargetFollower
from schemas.scenario import UNCERTAINTY_K, Laser

if TYPE_CHECKING:
    from planner.service.handler import RequestHandler
    from planner.service.ports import ClosedLoopPort, TrackPort
    from schemas.messages import TargetRequest


#: rad/s: a track request starts only while every joint is slower than this
REST_SPEED = 0.01
#: rad: farther than this from the first estimate's solution, the arm goes there with a
#: planned trajectory before the stream starts (the stream's first setpoint must lie within
#: 0.01 rad of the arm)
APPROACH_GAP = 0.005
#: s past the approach's planned end the robots may take to rest on its last sample
APPROACH_TIMEOUT = 2.0


def approach(node: ClosedLoopPort, handler: RequestHandler, plan: Plan, q0: Array, q1: Array,
             first: Array, normal: Array | None, request_id: str) -> Array:  # fmt: skip
    """Move from stacked ``q0`` to the first estimate's solution ``q1`` (rad) with a planned
    trajectory (timed and checked under the safety rules like any plan, laser off) and wait
    until every robot rests there; the measured joints then. ExecuteError when no safe move
    exists, a driver refuses it or the robots do not arrive."""

    system = handler.system
    if handler.closed_loop is None:
        raise ExecuteError("no planned approach to the tracked target (this planner has no "
                           "move planner): execute a request to it first", list(system.robot_names))  # fmt: skip
    traj = handler.closed_loop.move(q0, q1, 0.0, first, normal)
    traj = dataclasses.replace(traj, laser_on=traj.laser_on[:0])  # laser off throughout
    mini = dataclasses.replace(plan, trajectory=traj)
    sent = node.execution.execute(mini, f"{request_id[:200]}.approach", node.session_id)
    if sent.execution is not Verdict.ACCEPTED:
        raise ExecuteError(f"approach to the tracked target refused: {sent.execution_reason}",
                           list(system.robot_names))  # fmt: skip
    deadline = time.monotonic() + float(traj.t[-1]) + APPROACH_TIMEOUT
    q_end = {r: np.array(traj.q[r][-1], dtype=float) for r in system.robot_names}
    while not node.joints.rests_at(q_end):
        if time.monotonic() > deadline:
            raise ExecuteError(f"the robots did not reach the tracked target's first estimate "
                               f"within {APPROACH_TIMEOUT:g} s of the approach's end",
                               list(system.robot_names))  # fmt: skip
        time.sleep(0.005)
    return system.stack_q(node.joints.current())


# long: the start of tracking: checks, approach plan, follower and first setpoint, in the order they must happen
def start_track(node: TrackPort, req: TargetRequest) -> Plan:
    """Start following the target stream of a validated ``mode: track`` request on a
    :class:`planner.service.node.PlannerNode`; returns the reply document (the plan of the
    first estimate, ``execution: accepted``, ``tracking``). Errors (InputError /
    ExecuteError) name the field."""
    from planner.track.follow import MIN_MARKERS, TrackSettings

    if not req.execute:
        raise InputError("mode track moves the robots: it needs execute: true", "execute")
    handler, system = node.handler, node.handler.system
    if handler.track_ik is None:
        raise InputError("this planner has no tracking IK (no closed form for its arms)", "mode")
    node.check_drivers()
    start = node.joints.current()
    for robot in system.robot_names:
        entry = node.joints.get(robot)
        speed = 0.0 if entry is None else float(np.abs(entry[2]).max())
        if speed > REST_SPEED:
            raise ExecuteError(f"{robot} moves at {speed:.3f} rad/s: track once it rests",
                               [robot])  # fmt: skip
    targets = handler.targets(req, start)
    first = targets.points[0]
    normal = None if targets.normals is None else targets.normals[0]
    one = Targets(first[None], None if normal is None else normal[None], kind="points",
                  surface_tolerance=targets.surface_tolerance)  # fmt: skip
    plan = dataclasses.replace(handler.plan_fn(one, start, False), id=req.id)
    sol = plan.solutions[0]
    if sol.status is not Status.OK:
        raise ExecuteError(f"the target's first estimate is not reachable: {sol.reason}",
                           list(system.robot_names))  # fmt: skip
    q0 = system.stack_q(start)
    q1 = system.stack_q(dict(sol.q))
    base = node.track_settings or TrackSettings()
    if req.tolerance is not None and req.tolerance > base.tolerance:
        raise InputError(f"may only tighten the tracking laser-on tolerance "
                         f"{1e3 * base.tolerance:g} mm, got {1e3 * req.tolerance:g} mm",
                         "tolerance")  # fmt: skip
    settings = dataclasses.replace(base, tolerance=req.tolerance or base.tolerance)
    gap = float(np.abs(q1 - q0).max())
    if gap > APPROACH_GAP:  # the first move is a planned, checked trajectory, not a stream
        q0 = approach(node, handler, plan, q0, q1, first, normal, req.id)
    cam = None if system.camera is None else system.camera.world_T_camera
    scenario = plan.resolved
    attached = {o.name: o.world_T_object.matrix() for o in scenario.keep_out
                if o.attached_to == req.id}  # fmt: skip
    rest = targets.points[1:]  # the object's markers: the request's points after the target
    markers = rest if attached and len(rest) >= MIN_MARKERS else None
    rules = handler.track_ik.safety
    follower = TargetFollower(handler.track_ik, q0, first, cam, settings, attached=attached,
                              markers=markers,
                              check=None if rules is None else rules.twin())  # fmt: skip
    follower.warm_up(q1, normal)  # the first frame must not pay for first calls
    laser = scenario.laser
    allowance = None
    if scenario.keep_out:  # the rules check the model's beam: the bias must fit in the
        # padding's calibration part (the beam radius part is the beam's own width)
        allowance = UNCERTAINTY_K * scenario.safety.spot_uncertainty
    correction, why = camera_correction(req, system, laser, settings.tolerance, allowance)
    gate = None if laser is None else laser.gate
    node.track = TrackSession(node.session, node.keys, node.session_id, system, follower,
                              req.id, duration=req.duration,
                              gate_robot=None if gate is None else gate.robot,
                              aim=laser is not None and laser.aim is not None,
                              correction=correction,
                              send_stop=node.send_stop, on_end=node.track_ended).start()  # fmt: skip
    tracking = TrackingReport(req.id, req.duration, settings.tolerance, settings.rate, why)
    return dataclasses.replace(plan, execution=Verdict.ACCEPTED, tracking=tracking)


def camera_correction(
    req: TargetRequest, system: Any, laser: Laser | None, tolerance: float,
    max_bias: float | None = None,
) -> tuple[SpotCorrection | None, str]:  # fmt: skip
    """The camera-frame spot correction of a track request
    (:class:`planner.track.correction.SpotCorrection`) and what the reply says of it: on for
    targets in the camera frame of a fixed camera that can see the beam while the treatment
    is off (an aiming beam, or an ungated simulated laser, always on); otherwise off, and
    why. ``max_bias`` (m): with keep-out volumes, the calibration part of their padding
    (:data:`~schemas.scenario.UNCERTAINTY_K` x ``safety.spot_uncertainty``)."""
    if req.frame != "camera":
        return None, "off: targets in the world frame"
    if system.camera is None:
        return None, "off: no camera"
    if system.camera.robot is not None:  # frames and spots would map through other joints
        return None, "off: the camera moves with an arm"
    if laser is not None and laser.gate is not None and laser.aim is None:
        return None, "off: no aiming beam (laser.aim) to measure the spot with"
    return SpotCorrection(system, system.world_T_camera, tolerance=tolerance,
                          max_bias=max_bias), "on"  # fmt: skip
