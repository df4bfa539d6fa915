"""Tracking on the simulated cell, in one process: the simulation behind ``bench track`` and
``study moving-target``.

In one process, on a simulated clock (deterministic for a seed): the simulated tracker
(:class:`drivers.camera.tracker.SimTracker`, D435 marker noise, 30 Hz, its ``latency``)
reports the first target of ``scenarios/breathing.yaml`` on the moving phantom; the planner's
:class:`planner.track.follow.TargetFollower` (Kalman prediction, closed-form IK nearest the
current command with the scenario's safety rules, 500 Hz limited setpoints) follows it; the
arm reaches each setpoint at its time ``t`` (an ideal follower: the setpoint's own lead is
the only actuation delay); the simulated camera (:class:`drivers.camera.sim.SimCamera`)
traces the true beam at the arm's joints onto the phantom where its motion puts it. Spot
error = |true spot - true target| every 5th control period (100 Hz), over the periods with the laser
on (and over all, for comparison). Cases: (a) ``linear``: the phantom moves in its plane at
20 mm/s for 2.5 s, then back; (b) ``breathing``: the scenario's own sine, 5 mm at 0.25 Hz
along its normal; (c) ``face``: ``scenarios/face_tracking.yaml``, a head that breathes and
turns with keep-out eyes attached to it, the target 6.4 mm from an eye, the eyes moved by
the four markers' rigid motion. The latency is wall time from a frame's receipt to its first
setpoint: the follower's processing (prediction, two IK solves, the beam Jacobian) plus the
wait for the next control period. The safety check of each setpoint (the configuration and
the sweep from the last one, :meth:`~planner.track.follow.TargetFollower.setpoint`) is timed
on its own: configurations checked per second of checking (CPU), and the latency it adds
to each setpoint (wall and CPU time, p50 and p99).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from drivers.robot.servo_lag import ServoLag, ServoSettings
from planner.data import shipped_scenario
from planner.model.motion import ObjectMotion
from planner.model.scene import tracked_objects

#: the true spot is traced every SPOT_EVERY control periods (100 Hz)
SPOT_EVERY = 5
CASES: dict[str, tuple[str, ObjectMotion | None]] = {
    "linear": ("breathing.yaml", ObjectMotion.linear([0.02, 0.0, 0.0], 2.5)),
    "breathing": ("breathing.yaml", None),  # the scenario's own motion
    "face": ("face_tracking.yaml", None),
}


def timed_follower(*args: Any, **kw: Any) -> Any:
    """A :class:`~planner.track.follow.TargetFollower` that times each setpoint's safety
    check (s, in ``check_times``)."""
    from planner.track.follow import TargetFollower

    class Timed(TargetFollower):
        check_times: list[tuple[float, float]]

        def _violation(self, q: Any) -> str | None:
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return super()._violation(q)
            finally:
                self.check_times.append((time.perf_counter() - t0, time.thread_time() - c0))

    f = Timed(*args, **kw)
    f.check_times = []
    return f


def run_case(
    motion: ObjectMotion | None, seconds: float, seed: int, latency: float = 0.02,
    scenario: str = "breathing.yaml", robot_error: str = "none", servo_lag: bool = False,
    lookahead: float | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Simulate ``seconds`` s of tracking the first target of a shipped ``scenario`` on its
    moving object (the motion replaced by ``motion`` when given); with keep-out volumes
    attached to the object, its other targets are the markers; figures in m and s.
    ``robot_error`` (:data:`planner.model.kinematic_error.LEVELS`): the true arm, which the
    camera sees, gets DH deltas of that spread (drawn from ``seed``) while the follower keeps
    the nominal model; ``servo_lag``: the arm follows its setpoints as servoJ does
    (:class:`drivers.robot.servo_lag.ServoLag`, the UR driver's settings, or servoJ's
    ``lookahead`` time in s when given) instead of
    reaching each at its time."""
    from drivers.camera.sim import SimCamera
    from drivers.camera.tracker import SimTracker
    from planner.ik import BeamIK
    from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
    from planner.io.scenario import targets_from_scenario as targets_of
    from planner.plan.scenario_planner import ik_options
    from planner.safety.model import Safety
    from planner.track.follow import TrackSettings

    scn = load_scenario(shipped_scenario(scenario))
    system = system_from_scenario(scn)
    items = scene_objects(scn)
    if motion is not None:
        items = [dataclasses.replace(i, motion=motion) if i.motion else i for i in items]
    targets = targets_of(scn, system)
    obj = tracked_objects(items, targets.points, targets.normals)[0]
    assert system.camera is not None
    clock = [0.0]
    truth = true_arm(system_from_scenario(scn, truth=True), robot_error, seed)
    cam = SimCamera(truth, items, seed=seed, clock=lambda: clock[0])
    attached = {o.name: o.world_T_object.matrix() for o in scn.model.keep_out
                if o.attached_to == obj.item.name}  # fmt: skip
    if not attached:
        obj = dataclasses.replace(
            obj, points=obj.points[:1], normals=None if obj.normals is None else obj.normals[:1]
        )
    tracker = SimTracker([obj],
                         system.camera.world_T_camera, system.camera.intrinsics.fx, seed)  # fmt: skip
    ik = BeamIK(system, ik_options(scn.model.solver), Safety.from_scenario(scn, system))
    first = obj.points[0]
    normal = None if obj.normals is None else obj.normals[0]
    q0 = ik.solve(first, normal).q
    assert q0 is not None
    settings = TrackSettings()
    markers = obj.points[1:] if attached else None
    follower = timed_follower(ik, q0, first, system.camera.world_T_camera, settings,
                              attached=attached, markers=markers)  # fmt: skip
    lag = None
    if servo_lag:
        servo = ServoSettings() if lookahead is None else ServoSettings(lookahead_time=lookahead)
        lag = ServoLag(q0, servo, dt=1.0 / settings.rate)
    return _simulate(follower, tracker, cam, clock, system, seconds, latency, lag)


def true_arm(truth: Any, level: str, seed: int) -> Any:
    """``truth`` with its first arm's kinematics off the nominal by a draw of ``level``."""
    from planner.model.kinematic_error import LEVELS, true_robot

    spread = LEVELS[level]
    if spread is None:
        return truth
    arm = true_robot(truth.robots[0], spread, np.random.default_rng([seed, 1]))  # own stream
    return dataclasses.replace(truth, robots=(arm, *truth.robots[1:]))


def _simulate(
    follower: Any, tracker: Any, cam: Any, clock: list[float], system: Any, seconds: float,
    latency: float, lag: Any = None,
) -> dict[str, Any]:  # fmt: skip
    st = follower.settings
    dt, frame_dt = 1.0 / st.rate, 1.0 / st.frame_rate
    pending: list[tuple[float, Any]] = []  # (receipt time, message)
    arm: list[tuple[float, np.ndarray, bool]] = []  # setpoints: (t, q, laser)
    q_arm, laser = follower.q.copy(), False
    command = q_arm.copy()  # the last setpoint the arm was sent
    errors, lit, proc, lat, cpu = [], [], [], [], []
    robot = system.robot_names[0]
    obj = tracker.objects[0]
    frames = 0
    for k in range(round(seconds / dt)):
        now = k * dt
        while frames * frame_dt <= now + 1e-12:  # captures up to now, received latency later
            t_c = frames * frame_dt
            pending += [(t_c + latency, m) for m in tracker.measure(t_c)]
            frames += 1
        while pending and pending[0][0] <= now + 1e-12:
            r, msg = pending.pop(0)
            t0, c0 = time.perf_counter(), time.thread_time()
            normal = None if msg.normals is None else np.asarray(msg.normals[0])
            points = np.asarray(msg.points)
            markers = points[1:] if follower.markers is not None else None
            follower.on_frame(msg.t, points[0], normal, r, markers=markers)
            busy = time.perf_counter() - t0
            proc.append(busy)
            cpu.append(time.thread_time() - c0)
            lat.append(np.ceil((r + busy) / dt - 1e-9) * dt - r)  # to the next period's setpoint
        sp = follower.setpoint(now)
        if sp is not None:
            arm.append((sp[0], sp[1], sp[3]))
        while arm and arm[0][0] <= now + 1e-9:  # the setpoints due by now
            _, command, laser = arm.pop(0)
        # the arm is at the last one, or servoJ pulls it toward it (a cycle a period)
        q_arm = command if lag is None else lag.step(command)[0]
        follower.on_joint_state(q_arm, now)
        if k % SPOT_EVERY:
            continue
        clock[0] = now
        cam.grab()
        cam.on_joint_state(robot, system.split_q(q_arm)[robot])
        hit = cam.true_spot_world()
        true = tracker.true_points(obj, now)[0]
        errors.append(np.inf if hit is None else float(np.linalg.norm(hit[0] - true)))
        lit.append(laser and follower.stopped is None)
    out = _figures(np.asarray(errors), np.asarray(lit), np.asarray(proc), np.asarray(lat),
                   follower, seconds)  # fmt: skip
    out["cpu_p50_s"], out["cpu_p99_s"] = np.percentile(cpu, [50, 99]).tolist()
    return out


def _figures(
    err: np.ndarray, lit: np.ndarray, proc: np.ndarray, latency: np.ndarray, follower: Any,
    seconds: float,
) -> dict[str, Any]:  # fmt: skip
    settle = round(len(err) / seconds)  # the first second: the filter converges
    e, on = err[settle:], lit[settle:]
    out: dict[str, Any] = {
        "stopped": follower.stopped,
        "laser_on_fraction": float(on.mean()),
        "frames": len(proc),
        "manoeuvres": int(getattr(follower.predictor, "manoeuvres", 0)),
        "processing_p50_s": float(np.percentile(proc, 50)),
        "processing_p99_s": float(np.percentile(proc, 99)),
        "latency_p50_s": float(np.percentile(latency, 50)),
        "latency_p99_s": float(np.percentile(latency, 99)),
        **_check_figures(follower),
    }
    for name, sel in (("laser_on", on), ("all", np.ones_like(on))):
        x = e[sel.astype(bool) & np.isfinite(e)]
        out[f"rms_{name}_m"] = float(np.sqrt(np.mean(x**2))) if len(x) else None
        out[f"p95_{name}_m"] = float(np.percentile(x, 95)) if len(x) else None
        out[f"max_{name}_m"] = float(x.max()) if len(x) else None
    return out


def _check_figures(follower: Any) -> dict[str, float]:
    """Setpoint safety checks: configurations checked per second of checking (CPU), the
    wall time each setpoint's check took (s, p50 / p99) and its CPU time (p50 / p99)."""
    times = np.asarray(follower.check_times).reshape(-1, 2)
    if not len(times):
        return {}
    wall, cpu = times[:, 0], times[:, 1]
    return {"checked": int(follower.checked),
            "checks_per_cpu_s": float(follower.checked / max(cpu.sum(), 1e-9)),
            "check_p50_s": float(np.percentile(wall, 50)),
            "check_p99_s": float(np.percentile(wall, 99)),
            "check_cpu_p50_s": float(np.percentile(cpu, 50)),
            "check_cpu_p99_s": float(np.percentile(cpu, 99))}  # fmt: skip
