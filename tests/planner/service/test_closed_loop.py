"""Closed-loop execution as the node runs it, in-process: the runner against a fake bus side
(trajectories "played" by moving the simulated camera's arm, camera frames streamed into the
spot buffer at 30 Hz by a thread), plus the watchdog and the request checks."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import numpy as np
import pytest

from planner.bench.servo_world import UP, SimWorld, board_targets
from planner.errors import InputError
from planner.io.plan import Plan
from planner.io.plan import Trajectory as PlanTrajectory
from planner.model.settings import TrajectorySettings
from planner.model.status import Interruption, ServoStatus
from planner.model.system import Targets
from planner.service.closed_loop import (
    FRAME_PERIOD,
    ClosedLoopConfig,
    ClosedLoopRunner,
    Motion,
    check_closed_loop,
    execute_closed_loop,
    make_move_fn,
)
from planner.service.guard import Progress
from planner.service.handler import make_plan_fn
from planner.service.spots import LaserLog, SpotBuffer
from planner.servo import Corrector, ServoSettings
from schemas.messages import TargetRequest
from tests.fake_clock import FakeClock, Timeline


@pytest.fixture(scope="module")
def world() -> SimWorld:
    return SimWorld(seed=13)


#: s: the driver's approach: the laser switches on this long after the ack
GATE_DELAY = 0.05


class FakeBus:
    """Plays each trajectory at once (the arm jumps to its end) and streams the simulated
    camera's frames at 30 Hz while its laser-on interval lasts (a gated laser: no frames
    otherwise), all as events on a simulated clock (:class:`Timeline`, UNIX s) that the
    runner's waits move on; a trajectory sent during another's dwell waits for it (the
    driver queues)."""

    def __init__(self, world: SimWorld, *, reject_second_target: bool = False,
                 stop_at: int | None = None, gated: bool = False,
                 stop_after: float | None = None) -> None:  # fmt: skip
        self.world = world
        self.q = world.model.home
        self.sent: list[tuple[str, dict[str, Any]]] = []
        self.sent_at: list[float] = []  # simulated time of each send
        self.spots = SpotBuffer()
        self.stop = threading.Event()
        self.clock = Timeline(1.7e9, self.stop.is_set)
        self.reject_second, self.stop_at = reject_second_target, stop_at
        self.stop_after = stop_after  # s after the (first) send: the operator stops
        self.laser = LaserLog() if gated else None
        self.lie: Any = None  # (move number, p_camera, confidence) -> (p_camera, confidence)

    def send(self, move: PlanTrajectory, move_id: str) -> tuple[str, str | None]:
        traj = move.to_document()  # what the drivers are sent
        self.clock.run_all()  # the previous move's dwell plays out first
        self.sent.append((move_id, traj))
        self.sent_at.append(self.clock())
        q_end = self.world.model.stack_q({r: q[-1] for r, q in traj["q"].items()})
        far = len(self.sent) > 1 and np.max(np.abs(q_end - self.q)) > 0.01  # a new target
        if self.reject_second and far:
            return "rejected", "arm0: simulated refusal"
        self.q = q_end
        lit = (traj.get("laser_on") or []) + (traj.get("aim_on") or [])  # either beam is seen
        self._frames(self.q.copy(), sum(b - a for a, b in lit))
        if self.stop_at is not None and len(self.sent) >= self.stop_at:
            self.stop.set()
        if self.stop_after is not None and len(self.sent) == 1:
            self.clock.at(self.clock() + self.stop_after, self.stop.set)
        return "accepted", None

    def _frames(self, q: np.ndarray, on: float) -> None:
        t0 = self.clock() + GATE_DELAY
        if self.laser is not None:
            self.clock.at(t0, lambda: self.laser and self.laser.offer(t0, True))
        for i in range(int(on / FRAME_PERIOD) + 1):
            self.clock.at(t0 + i * FRAME_PERIOD, lambda: self._frame(q))
        if self.laser is not None:
            self.clock.at(t0 + on, lambda: self.laser and self.laser.offer(t0 + on, False))

    def _frame(self, q: np.ndarray) -> None:
        f = self.world.frames(q, 1)[0]
        p = None if f.p_camera is None else f.p_camera.tolist()
        c = f.confidence
        if self.lie is not None and p is not None:
            p, c = self.lie(len(self.sent), np.asarray(p), c)
            p = p.tolist()
        self.spots.offer(self.clock(), p, c)

    def rest_at(self, q: np.ndarray) -> bool:
        return bool(np.allclose(self.q, q, atol=1e-12))

    def motion(self, ticks: list[float]) -> Motion:
        return Motion(self.send, self.rest_at, self.spots, self.stop,
                      lambda: ticks.append(self.clock()), self.laser, clock=self.clock,
                      wait=self.clock.wait)  # fmt: skip


def config_of(world: SimWorld, settings: ServoSettings | None = None) -> ClosedLoopConfig:
    return ClosedLoopConfig(Corrector(world.model), make_move_fn(world.model, TrajectorySettings()),
                            0.3, settings or ServoSettings(), aim=True)  # fmt: skip


def _run(world: SimWorld, bus: FakeBus, k: int, dwell: float | None = 0.1,
         settings: ServoSettings | None = None) -> dict[str, Any]:  # fmt: skip
    model = world.model
    P = board_targets(k, seed=4)
    targets = Targets(P, np.tile(UP, (k, 1)))
    planned = make_plan_fn(model, {})(targets, None, False)
    req = TargetRequest.model_validate({"schema": "beamrelay.request/1", "id": "cl", "execute": True,
                                        "closed_loop": True, "points": P.tolist(), "dwell": dwell})  # fmt: skip
    config = config_of(world, settings)
    ticks: list[float] = []
    check_closed_loop(req, model, config)
    done = execute_closed_loop(planned, targets, req, model.home, config, bus.motion(ticks), model)
    bus.clock.run_all()
    plan = done.to_document()  # the reply
    text = json.dumps(plan)  # the typed report reads back from the reply exactly
    assert json.dumps(Plan.from_document(json.loads(text)).to_document()) == text
    plan["_ticks"] = ticks
    plan["_targets"] = P
    return plan


@pytest.mark.parametrize("gated", [False, True])
def test_every_target_converges_and_the_laser_is_on_only_at_rest(
    world: SimWorld, gated: bool
) -> None:
    bus = FakeBus(world, gated=gated)
    plan = _run(world, bus, 2)
    rows = plan["closed_loop"]["targets"]
    assert plan["execution"] == "accepted" and plan["execution_reason"] is None
    assert [r["status"] for r in rows] == ["converged", "converged"]
    assert all(r["measured_error_before"] > 3e-3 for r in rows)
    assert all(r["measured_error_after"] <= 0.3e-3 and r["frames"] <= 25 for r in rows)
    assert all(r["dwell"] == 0.1 for r in rows)
    spot = world.true_spot(bus.q)  # independent: the truth's spot where the arm was left
    assert spot is not None and np.linalg.norm(spot - plan["_targets"][-1]) <= 0.5e-3
    extra = plan["metrics"]["extra"]
    assert extra["measured_error_max"] == max(r["measured_error_after"] for r in rows)
    assert extra["closed_loop_converged"] == 2.0 and len(plan["_ticks"]) >= len(bus.sent)
    treated = [traj for _, traj in bus.sent if traj["laser_on"]]
    aimed = [traj for _, traj in bus.sent if traj.get("aim_on")]
    # aim, then treat: every move is a measurement with the aiming beam, or a treatment
    # dwell of a converged target (one per target, the last move to it)
    assert len(treated) == 2 and len(aimed) == len(bus.sent) - 2
    assert all(not traj["laser_on"] for traj in aimed)
    assert all(not traj.get("aim_on") for traj in treated)
    assert all(r["treated"] for r in rows)
    for _, traj in bus.sent:  # either beam only while every joint rests, always at the end
        t = np.asarray(traj["t"])
        spans = traj["laser_on"] or traj["aim_on"]
        for a, b in spans:
            inside = (t >= a) & (t <= b)
            for qd in traj["qd"].values():
                assert np.max(np.abs(np.asarray(qd)[inside])) < 1e-9
        assert spans[-1][1] == pytest.approx(t[-1])


@pytest.mark.parametrize("settings", [ServoSettings(max_iterations=0),
                                      ServoSettings(tolerance=1e-7, max_iterations=2)])  # fmt: skip
def test_a_target_that_does_not_converge_is_reported_and_never_treated(
    world: SimWorld, settings: ServoSettings
) -> None:
    bus = FakeBus(world, gated=True)
    plan = _run(world, bus, 2, dwell=0.2, settings=settings)
    rows = plan["closed_loop"]["targets"]
    print([(r["status"], r["measured_error_after"]) for r in rows])
    assert all(r["status"] in ("max_iterations", "not_improving") for r in rows)
    assert all(r["treated"] is False and r["dwell"] == 0.0 for r in rows)
    assert not any(traj["laser_on"] for _, traj in bus.sent)  # the treatment gate never opens
    assert all(traj["aim_on"] for _, traj in bus.sent)  # every move was a measurement


def test_a_stop_aborts_at_once_and_nothing_more_is_sent(world: SimWorld) -> None:
    bus = FakeBus(world, stop_at=2)
    plan = _run(world, bus, 3)
    rows = plan["closed_loop"]["targets"]
    assert len(bus.sent) == 2
    assert [r["status"] for r in rows] == ["aborted"] * 3
    assert "stop" in plan["execution_reason"] and rows[0]["dwell"] == 0.0
    assert [r["treated"] for r in rows] == [False] * 3  # every row says so, not only treated ones


def test_a_rejected_move_ends_the_run_naming_the_target(world: SimWorld) -> None:
    bus = FakeBus(world, reject_second_target=True)
    plan = _run(world, bus, 3)
    rows = plan["closed_loop"]["targets"]
    assert plan["execution"] == "rejected"
    assert plan["execution_reason"].startswith("target 1: arm0: simulated refusal")
    assert [r["status"] for r in rows] == ["converged", "rejected", "not_executed"]
    report = Plan.from_document(plan).closed_loop  # the reply, typed
    assert (
        report is not None
        and report.converged == 1 == plan["metrics"]["extra"]["closed_loop_converged"]
    )
    first, refused, rest = report.targets
    assert (refused.status, refused.reason) == (ServoStatus.REJECTED, Interruption.EXECUTION)
    assert (rest.status, rest.treated, rest.servo) == (ServoStatus.NOT_EXECUTED, None, None)
    assert first.servo is not None and first.servo.error_after is not None
    assert first.servo.error_after <= 0.3e-3 and first.servo.spot is not None


def _req(**kw: Any) -> TargetRequest:
    body = {"schema": "beamrelay.request/1", "id": "x", "points": [[0.0, 0.0, 0.1]] * 2} | kw
    return TargetRequest.model_validate(body)


@pytest.mark.parametrize(
    "kw, text",
    [({"closed_loop": True}, "needs execute"),
     ({"closed_loop": True, "execute": True, "mode": "path"}, "mode points")],
)  # fmt: skip
def test_closed_loop_requests_that_cannot_be_served_name_the_field(
    world: SimWorld, kw: dict[str, Any], text: str
) -> None:
    with pytest.raises(InputError, match=text) as info:
        check_closed_loop(_req(**kw), world.model)
    assert info.value.where == "closed_loop"
    check_closed_loop(_req(), world.model)  # open loop: nothing to check
    from dataclasses import replace

    with pytest.raises(InputError, match="camera"):
        check_closed_loop(_req(closed_loop=True, execute=True), replace(world.model, camera=None))


def test_closed_loop_without_an_aiming_beam_or_with_a_looser_tolerance_is_refused(
    world: SimWorld,
) -> None:
    model = world.model
    config = ClosedLoopConfig(Corrector(model), make_move_fn(model, TrajectorySettings()), 0.3,
                              ServoSettings(tolerance=3e-4), gated=True, aim=False)  # fmt: skip
    req = _req(closed_loop=True, execute=True)
    with pytest.raises(InputError, match=r"laser\.aim") as info:
        check_closed_loop(req, model, config)
    assert info.value.where == "closed_loop"
    aimed = replace_config(config, aim=True)
    check_closed_loop(req, model, aimed)
    check_closed_loop(_req(closed_loop=True, execute=True, tolerance=1e-4), model, aimed)  # tighter
    with pytest.raises(InputError, match=r"only tighten .* 0\.3 mm, got 2 mm") as info:
        check_closed_loop(_req(closed_loop=True, execute=True, tolerance=2e-3), model, aimed)
    assert info.value.where == "tolerance"


def replace_config(config: ClosedLoopConfig, **kw: Any) -> ClosedLoopConfig:
    from dataclasses import replace

    return replace(config, **kw)


@pytest.mark.parametrize("bad", [{"tolerance": 0.0}, {"tolerance": 0.5}, {"dwell": -1.0},
                                 {"closed_loop": "yes"}, {"tolerance": float("nan")}])  # fmt: skip
def test_bad_closed_loop_fields_are_refused_by_the_schema(bad: dict[str, Any]) -> None:
    with pytest.raises(InputError) as info:
        from planner.bus.session import decode

        decode(__import__("json").dumps({"schema": "beamrelay.request/1", "id": "x",
                                         "points": [[0, 0, 0.1]], **bad}).encode(),
               TargetRequest)  # fmt: skip
    assert info.value.where == next(iter(bad))


def test_a_ticking_job_is_not_wedged_but_a_silent_one_is() -> None:
    clock = FakeClock()
    p = Progress(timeout=0.2, per_target=0.0, clock=clock)
    p.begin()
    for _ in range(8):
        clock.advance(0.15)
        p.tick()
        assert p.overdue() is None
    clock.advance(0.2 - 1e-6)
    assert p.overdue() is None
    clock.advance(2e-6)
    assert "busy on one request for 0.2 s (allowed 0.2 s)" in (p.overdue() or "")
    p.end()
    p.tick()  # no job: nothing to extend
    assert p.overdue() is None


def test_spot_buffer_collects_the_window_and_honours_stop() -> None:
    clock = Timeline(1.7e9)
    buf = SpotBuffer()
    t = clock()
    for i in range(5):
        buf.offer(t + 0.01 * i, [0.0, 0.0, 1.0 + i], 0.5)
    got = buf.collect(t + 0.015, t + 0.035, 5, lambda: False, latency=0.0, clock=clock,
                      wait=clock.wait)  # fmt: skip
    assert [f.p_camera[2] for f in got if f.p_camera is not None] == [3.0, 4.0]
    assert clock() - t == pytest.approx(0.04, abs=1e-6)  # waited past t1 + latency, no more
    t = clock()
    assert buf.collect(t + 10, t + 20, 3, lambda: True, clock=clock, wait=clock.wait) == []
    assert clock() == t  # a stop: at once
    for i in range(3):  # frames arriving while it waits: done at the third
        clock.at(t + 0.1 * (i + 1), lambda i=i: buf.offer(t + 0.1 * (i + 1), [0, 0, 9.0], 0.5))
    got = buf.collect(t + 0.05, t + 10, 3, lambda: False, clock=clock, wait=clock.wait)
    assert [f.p_camera[2] for f in got if f.p_camera is not None] == [9.0] * 3
    assert t + 0.3 <= clock() <= t + 0.31 + 1e-6  # the first look after the third (10 ms polls)


@pytest.mark.parametrize(("stop_after", "dwelt"), [(None, 0.25), (0.03, 0.03)])
def test_hold_dwells_exactly_from_the_rest_and_a_stop_cuts_it(
    world: SimWorld, stop_after: float | None, dwelt: float
) -> None:
    bus = FakeBus(world, stop_after=stop_after)
    runner = ClosedLoopRunner(world.model, config_of(world), bus.motion([]), "h", ServoSettings())
    t0 = bus.clock()
    assert runner.hold(0.25) == pytest.approx(dwelt, abs=1e-6)
    assert bus.clock() - t0 == pytest.approx(dwelt, abs=1e-6)  # the robots rest at once
    ((_, traj),) = bus.sent
    assert traj["laser_on"] and not traj.get("aim_on")  # the treatment gate
    assert sum(b - a for a, b in traj["laser_on"]) == pytest.approx(0.25, abs=1e-9)


def test_joint_cache_rests_at_only_when_fresh_still_and_on_the_joints() -> None:
    from planner.service.execution import AT_Q, JointCache

    cache = JointCache(("a", "b"))
    q = np.zeros(6)
    assert not cache.rests_at({"a": q})  # no state yet
    cache.update("a", q + 0.5 * AT_Q, np.zeros(6))
    assert cache.rests_at({"a": q})
    cache.update("a", q + 2 * AT_Q, np.zeros(6))
    assert not cache.rests_at({"a": q})  # off the commanded joints
    cache.update("a", q, np.full(6, 0.01))
    assert not cache.rests_at({"a": q})  # still moving
    cache.update("a", q, np.zeros(6))
    assert cache.rests_at({"a": q}) and not cache.rests_at({"a": q, "b": q})
    time.sleep(0.06)
    assert not cache.rests_at({"a": q}, max_age=0.05)  # stale


def test_a_refusal_caused_by_a_stop_counts_as_aborted(world: SimWorld) -> None:
    bus = FakeBus(world, reject_second_target=True)
    send = bus.send

    def stop_then_refuse(traj: dict[str, Any], move_id: str) -> tuple[str, str | None]:
        verdict, reason = send(traj, move_id)
        if verdict == "rejected":
            bus.stop.set()  # the stop that made the driver refuse
        return verdict, reason

    bus.send = stop_then_refuse  # type: ignore[method-assign]
    plan = _run(world, bus, 3)
    rows = plan["closed_loop"]["targets"]
    assert [r["status"] for r in rows] == ["converged", "aborted", "aborted"]
    assert plan["execution"] == "accepted" and "stop" in plan["execution_reason"]


def test_laser_log_spans_begin_after_a_time_and_end_on_the_off_switch() -> None:
    log = LaserLog()
    log.offer(10.0, True)
    log.offer(10.5, True)  # a status repeat: no new span
    log.offer(11.0, False)
    log.offer(12.0, True)
    assert log.span_after(9.0) == (10.0, 11.0) and log.span_after(10.2) == (12.0, float("inf"))
    clock = Timeline(100.0)
    wait = {"clock": clock, "wait": clock.wait}
    assert log.wait_span(10.2, 0.1, lambda: False, **wait) is None  # still on after the timeout
    assert 100.1 <= clock() <= 100.1 + 0.01 + 1e-9  # the first look past 0.1 s (10 ms polls)
    clock.at(100.5, lambda: log.offer(12.4, False))
    assert log.wait_span(10.2, 1.0, lambda: False, **wait) == (12.0, 12.4)
    assert clock() == pytest.approx(100.5, abs=1e-9)
    assert log.span_after(13.0) is None and log.wait_span(13.0, 5.0, lambda: True, **wait) is None
    assert clock() == pytest.approx(100.5, abs=1e-9)


def test_three_implausible_spots_in_a_row_stop_the_closed_loop(world: SimWorld) -> None:
    bus = FakeBus(world, gated=True)
    # from the second move on, every spot the camera reports lies 30 mm to the side (the true
    # one is within a fraction of a mm of the prediction there)
    bus.lie = lambda n, p, c: (p + np.array([0.03, 0.0, 0.0]) if n >= 2 else p, c)
    plan = _run(world, bus, 2)
    rows = plan["closed_loop"]["targets"]
    assert plan["execution"] == "rejected"
    assert "3 implausible spots in a row (each over 5 mm from the predicted spot)" in (
        plan["execution_reason"])  # fmt: skip
    assert rows[0]["status"] == "rejected" and rows[1]["status"] == "not_executed"
    assert plan["closed_loop"]["dropped"]["implausible"] >= 3
    assert not any(traj["laser_on"] for _, traj in bus.sent)  # never treated


def test_low_confidence_frames_are_dropped_and_counted(world: SimWorld) -> None:
    bus = FakeBus(world, gated=True)
    k = iter(range(10_000))
    # every other frame comes with confidence 0.1 and a spot 20 mm off: dropped, not averaged
    bus.lie = lambda n, p, c: (p + 0.02, 0.1) if next(k) % 2 else (p, c)
    plan = _run(world, bus, 1)
    rows = plan["closed_loop"]["targets"]
    print(plan["closed_loop"]["dropped"], rows[0]["status"], rows[0]["measured_error_after"])
    assert rows[0]["status"] == "converged" and rows[0]["measured_error_after"] <= 0.3e-3
    assert plan["closed_loop"]["dropped"]["low_confidence"] >= 1
    assert plan["closed_loop"]["dropped"]["implausible"] == 0
    spot = world.true_spot(bus.q)  # independent: the truth's spot where the arm was left
    assert spot is not None and np.linalg.norm(spot - plan["_targets"][-1]) <= 0.5e-3


def test_the_predicted_spot_is_published_for_every_measurement(world: SimWorld) -> None:
    bus = FakeBus(world, gated=True)
    got: list[tuple[np.ndarray, float]] = []
    motion = bus.motion([])
    motion.predict = lambda p, t: got.append((np.asarray(p), t))
    model = world.model
    P = board_targets(1, seed=4)
    targets = Targets(P, np.tile(UP, (1, 1)))
    plan = make_plan_fn(model, {})(targets, None, False)
    req = TargetRequest.model_validate({"schema": "beamrelay.request/1", "id": "p", "execute": True,
                                        "closed_loop": True, "points": P.tolist(), "dwell": 0.1})  # fmt: skip
    config = ClosedLoopConfig(Corrector(model), make_move_fn(model, TrajectorySettings()), 0.3,
                              ServoSettings(), aim=True)  # fmt: skip
    execute_closed_loop(plan, targets, req, model.home, config, motion, model)
    measurements = [t for _, t in bus.sent if t.get("aim_on")]
    assert len(got) == len(measurements) >= 2
    # the later predictions carry the measured offset: within a mm of the true spot there
    cam = model.world_T_camera(model.home)
    true = world.true_spot(bus.q)
    assert true is not None
    last = cam[:3, :3] @ got[-1][0] + cam[:3, 3]
    assert np.linalg.norm(last - true) < 1e-3
