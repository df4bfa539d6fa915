"""``mode: track`` on the bus: setpoints follow the target stream; garbage and other ids
are ignored while the node keeps serving; other requests get "busy tracking"; a stale
stream turns the laser off, ends the stream and publishes a stop."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.robot.setpoint_check import STALE_AFTER
from planner.ik import BeamIK
from planner.service.node import PlannerNode, handler_from_scenario
from planner.track.follow import TrackSettings
from schemas.defaults import SERVO_RATE_HZ
from tests.drivers.conftest import wait_for
from tests.paths import SCENARIOS
from tests.planner.raw_zenoh import Inbox, ask
from tests.planner.service.fake_driver import PREFIX, NodeRig, NodeRigFactory

P0 = [-0.492, -0.55, -0.06]


@pytest.fixture
def rig(tmp_path: Path, node_rig: NodeRigFactory) -> NodeRig:
    text = (
        (SCENARIOS / "breathing.yaml")
        .read_text()
        .replace("rpy_deg: [40, 0, 0]}", "rpy_deg: [40, 0, 0]}\n    gate: {robot: arm0, output: 0}")
    )
    path = tmp_path / "breathing_gated.yaml"
    path.write_text(text)
    handler = handler_from_scenario(path)
    q0 = BeamIK(handler.system).solve(np.array(P0), np.array([0, 0, 1.0])).q

    def stale_after_10_frames(node: PlannerNode) -> None:
        # 10 frame periods (333 ms) before the stale stop: the test's own process publishes
        # the frames and parses 500 setpoints/s under the GIL of a shared, loaded machine
        node.track_settings = TrackSettings(stale_frames=10)

    return node_rig(handler, q0, stale_after_10_frames)


def request(client: Any, rid: str, **kw: Any) -> tuple[bool, dict[str, Any]]:
    body = {"schema": "beamrelay.request/1", "id": rid, "points": [P0], "normals": [[0, 0, 1]],
            **kw}  # fmt: skip
    ok, reply = ask(client, f"{PREFIX}/plan", json.dumps(body).encode())
    return ok, json.loads(reply)


def frame(rid: str, p: list[float]) -> bytes:
    return json.dumps({"schema": "beamrelay.target_stream/1", "t": time.time(), "id": rid,
                       "points": [p], "normals": [[0, 0, 1]]}).encode()  # fmt: skip


@pytest.mark.serial  # a real-time probe: 30 Hz frames in, 500 Hz setpoints out, for 1 s
def test_track_follows_ignores_garbage_refuses_others_and_stops_when_stale(rig) -> None:
    node, client, _ = rig
    setpoints = Inbox(client, f"{PREFIX}/arm0/setpoint")
    stops, plans = Inbox(client, f"{PREFIX}/stop"), Inbox(client, f"{PREFIX}/plans")
    ok, reply = request(client, "phantom", mode="track", execute=True)
    assert ok and reply["execution"] == "accepted" and reply["tracking"]["stream"] == "phantom"
    key = f"{PREFIX}/targets/stream"
    garbage = [b"\xff\xfe", b"[]", b'{"schema": "beamrelay.target_stream/1"}',
               frame("phantom", [float("nan"), 0, 0]).replace(b"NaN", b"1e400"),
               b"x" * 100_000, frame("someone-else", [0.3, 0.3, 0.3])]  # fmt: skip
    t_end = time.monotonic() + 1.0
    k = 0
    while time.monotonic() < t_end:  # 30 Hz frames, garbage in between
        x = P0[0] + 0.002 * np.sin(np.pi * time.monotonic())  # 2 mm at 0.5 Hz
        client.put(key, frame("phantom", [x, P0[1], P0[2]]))
        client.put(key, garbage[k % len(garbage)])
        k += 1
        time.sleep(1 / 30)
    assert node.track.active, node.track.summary
    # the follower hears the measured arm: the fake driver's arm stays at q0 while the
    # command follows the 2 mm sine, so the laser rule sees a gap (was always 0)
    assert node.track.follower.arm_gap > 0.0
    busy_ok, busy = request(client, "other")
    assert not busy_ok and "busy tracking 'phantom'" in busy["error"]
    live = setpoints.bodies()
    stamps = np.array([b["t"] for b in live])  # the streamer's own clock (UNIX s)
    gaps = np.diff(stamps)
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    print(f"setpoints: {len(live)} at {rate:.0f} Hz (nominal {SERVO_RATE_HZ:.0f}), longest gap "
          f"{1e3 * gaps.max():.1f} ms")  # fmt: skip
    # measured under a load average of 20 on 2 cores: 174-407 Hz, gaps 32-236 ms; the bound is
    # what a driver needs (a quiet machine), not what a loaded one gives
    assert rate >= 0.8 * SERVO_RATE_HZ
    assert gaps.max() < STALE_AFTER  # a driver would end the stream at this gap
    assert all(b["session"] == node.session_id and b["id"] == "phantom" for b in live)
    assert any(b["laser_on"] for b in live)
    # frames stop: stale after 10 frame periods -> laser off, stream ends, stop sent
    t_last = time.monotonic()
    wait_for(lambda: not node.track.active, 3.0, "the track session to end")
    times, bodies = setpoints.times(), setpoints.bodies()
    assert bodies[-1]["laser_on"] is False
    assert times[-1] - t_last < 1.0
    n = len(bodies)
    time.sleep(0.2)
    assert len(setpoints.bodies()) == n  # nothing after the end
    wait_for(lambda: len(stops.bodies()) >= 1, 2.0, "a stop message")
    assert "stale" in stops.bodies()[-1]["reason"]
    wait_for(lambda: any(isinstance(b, dict) and b.get("schema") == "beamrelay.track/1"
                         for b in plans.bodies()), 2.0, "the tracking summary")  # fmt: skip
    summary = next(b for b in plans.bodies() if isinstance(b, dict) and "ended" in b)
    assert summary["ignored"] >= len(garbage) and summary["frames"] >= 20
    assert summary["completed"] is False  # ended by a fault: `request --track` exits 1
    assert 0 < summary["latency_p50"] <= summary["latency_p99"]
    print(
        f"frame -> setpoint latency p50 {1e3 * summary['latency_p50']:.2f} ms, "
        f"p99 {1e3 * summary['latency_p99']:.2f} ms over {summary['frames']} frames"
    )
    ok, after = request(client, "after")  # serving again
    assert ok and after["solutions"][0]["status"] == "ok"


def test_stop_ends_tracking_and_track_needs_execute(rig) -> None:
    node, client, _ = rig
    ok, reply = request(client, "p2", mode="track")
    assert not ok and reply["field"] == "execute"
    ok, reply = request(client, "p2", mode="track", execute=True, duration=30)
    assert ok
    for _ in range(10):
        client.put(f"{PREFIX}/targets/stream", frame("p2", P0))
        time.sleep(1 / 30)
    assert node.track.active
    client.put(f"{PREFIX}/stop", b"{}")
    wait_for(lambda: not node.track.active, 2.0, "the session to end on stop")
    assert "stop seen" in node.track.summary["ended"]
    assert node.track.summary["completed"] is False


def test_a_track_that_runs_its_duration_is_completed(rig) -> None:
    node, client, _ = rig
    ok, _ = request(client, "p3", mode="track", execute=True, duration=0.3)
    assert ok
    t_end = time.monotonic() + 3.0
    while node.track.active and time.monotonic() < t_end:
        client.put(f"{PREFIX}/targets/stream", frame("p3", P0))
        time.sleep(1 / 30)
    wait_for(lambda: node.track.summary is not None, 2.0, "the tracking summary")
    assert node.track.summary["ended"].startswith("duration 0.3 s")
    assert node.track.summary["completed"] is True


def test_the_first_move_to_a_tracked_target_is_a_planned_trajectory(
    tmp_path: Path, node_rig: NodeRigFactory
) -> None:
    """The arm rests 0.1 rad from the first estimate's solution: the planner sends a planned
    approach (laser off) and streams only once the arm rests there, from there."""
    text = (SCENARIOS / "breathing.yaml").read_text().replace(
        "rpy_deg: [40, 0, 0]}", "rpy_deg: [40, 0, 0]}\n    gate: {robot: arm0, output: 0}")  # fmt: skip
    path = tmp_path / "breathing_gated.yaml"
    path.write_text(text)
    handler = handler_from_scenario(path)
    q1 = BeamIK(handler.system).solve(np.array(P0), np.array([0, 0, 1.0])).q
    assert q1 is not None
    q0 = q1 + np.array([0.0, 0.0, 0.0, 0.1, 0.0, 0.0])
    node, client, fake = node_rig(handler, q0)
    fake.arrive = True
    setpoints = Inbox(client, f"{PREFIX}/arm0/setpoint")
    ok, reply = request(client, "far", mode="track", execute=True, duration=0.5)
    assert ok and reply["execution"] == "accepted", reply
    approach = [t for t in fake.trajectories if t["id"].endswith(".approach")]
    assert len(approach) == 1 and not approach[0].get("laser_on")
    np.testing.assert_allclose(approach[0]["q"][0], q0, atol=1e-9)
    from planner.beam.trace import trace_beam

    q_end = np.asarray(approach[0]["q"][-1])  # the move ends on the target (numpy beam)
    assert trace_beam(handler.system, q_end, np.array(P0), np.array([0, 0, 1.0])).error < 1e-4
    client.put(f"{PREFIX}/targets/stream", frame("far", list(P0)))
    wait_for(lambda: len(setpoints.bodies()) > 5, 3.0, "setpoints")
    first = setpoints.bodies()[0]
    assert np.max(np.abs(np.asarray(first["q"]) - q_end)) < 0.01  # streamed from there
    wait_for(lambda: not node.track.active, 5.0, "the track session to end")


def test_a_track_request_may_only_tighten_the_laser_on_tolerance(rig: NodeRig) -> None:
    _, client, _ = rig
    ok, reply = request(client, "loose", mode="track", execute=True, tolerance=0.02)
    assert not ok and reply["field"] == "tolerance"
    assert "may only tighten the tracking laser-on tolerance 1 mm, got 20 mm" in reply["error"]
