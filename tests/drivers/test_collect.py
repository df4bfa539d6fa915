"""Calibration data collection: pose planning and conditioning, ChArUco corners from a
rendered image, and ``calibrate collect handeye|beam`` on the simulated system."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.camera.markers import CharucoSpec, detect_charuco
from planner.calibration.collect import (
    condition,
    handeye_jacobian,
    handeye_plan,
    min_jerk_move,
    select_conditioned,
)
from planner.calibration.dataset import load_beam
from planner.calibration.simulate import board_grid
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.system import Intrinsics
from planner.model.transforms import axis_angle_to_matrix, make_T
from planner.service.collect import Why
from planner.simcell.detectors import render_charuco
from tests import cli_run
from tests.drivers.conftest import free_port, raw_session, wait_for, wait_for_nodes
from tests.paths import REPO
from tests.planner.raw_zenoh import Inbox

SCENARIO = REPO / "scenarios" / "paper_n1.yaml"
CLI = [sys.executable, "-m", "planner.cli"]
ENV = dict(os.environ, PYTHONPATH=os.getcwd())


def test_min_jerk_move_peaks_at_the_speed() -> None:
    q0, q1 = np.zeros(6), np.array([0.4, -0.2, 0, 0, 0, 0.1])
    mv = min_jerk_move(q0, q1, 0.3)
    assert np.max(np.abs(mv.qd[:, 0])) == pytest.approx(0.3, rel=1e-3)
    np.testing.assert_allclose(mv.q[-1], q1, atol=1e-12)
    assert np.allclose(np.diff(mv.q, axis=0) / np.diff(mv.t)[:, None], mv.qd[1:], atol=2e-3)


class SegmentWorld:
    """A stand-in for the bus planner: the arm at ``q``; a move along one of ``blocked``
    (pairs of pose labels, either way) fails its safety check and leaves the arm; every other
    move arrives. Poses are labelled by their first joint."""

    def __init__(self, start: float, blocked: set[frozenset[float]]) -> None:
        self.q, self.blocked, self.moves = start, blocked, [start]

    def move(self, robot: str, target: Any, speed: float, world: Any) -> Why | None:
        to = float(np.asarray(target)[0])
        if frozenset((self.q, to)) in self.blocked:
            return Why(f"safety check: {self.q} -> {to} collides", collided=True)
        self.q = to
        self.moves.append(to)
        return None


def pose(label: float) -> Any:
    return np.array([label, 0, 0, 0, 0, 0], dtype=float)


def test_a_collection_returns_to_its_start_back_along_its_own_clear_moves() -> None:
    from planner.cli.collect import _return

    # out: 0 -> 1 -> 2 -> 3; straight back to 0 collides from 3 and from 2, not from 1
    bp = SegmentWorld(3.0, {frozenset((3.0, 0.0)), frozenset((2.0, 0.0))})
    line = _return(bp, "arm0", [pose(0), pose(1), pose(2), pose(3)], 1.0, None)
    assert bp.moves == [3.0, 2.0, 1.0, 0.0] and line == "returned to the start pose (3 moves)"
    bp = SegmentWorld(3.0, set())  # a clear way home: one move
    assert _return(bp, "arm0", [pose(0), pose(1), pose(3)], 1.0, None).endswith("(1 moves)")
    assert bp.moves == [3.0, 0.0]
    bp = SegmentWorld(0.0, set())
    assert _return(bp, "arm0", [pose(0)], 1.0, None) == "the arm is at its start pose"
    assert bp.moves == [0.0]
    # a move that ended early: where the arm stopped is unknown, it stays there
    bp = SegmentWorld(2.5, set())
    assert _return(bp, "arm0", None, 1.0, None).startswith("not returned to the start pose")
    assert bp.moves == [2.5]
    # the way back re-checked and now blocked (the scene changed): stops and says so
    bp = SegmentWorld(2.0, {frozenset((2.0, 0.0)), frozenset((2.0, 1.0))})
    line = _return(bp, "arm0", [pose(0), pose(1), pose(2)], 1.0, None)
    assert line.startswith("not returned to the start pose: safety check") and bp.moves == [2.0]


def test_conditioning_selection_and_degenerate_poses() -> None:
    system = system_from_scenario(load_scenario(SCENARIO))
    assert system.camera is not None
    board, pose = board_grid(), make_T(p=[0, 0, 0.01])
    rng = np.random.default_rng(0)
    qs, cond = handeye_plan(system, "arm0", "eye_to_hand", 6, board, pose, rng, oversample=4)
    cam = system.camera.world_T_camera
    J = handeye_jacobian(system, "arm0", "eye_to_hand", qs, board, cam, pose)
    assert J.shape == (6 * len(board) * 3, 12)
    assert cond == pytest.approx(condition(J), rel=1e-6)  # the reported figure is J's
    # rotating only wrist_3 leaves directions poorly excited: far worse conditioned
    q0 = qs[0]
    spin = np.array([q0 + np.array([0, 0, 0, 0, 0, a]) for a in np.linspace(-0.5, 0.5, 6)])
    bad = condition(handeye_jacobian(system, "arm0", "eye_to_hand", spin, board, cam, pose))
    assert bad > 10 * cond
    # greedy selection beats taking the first candidates
    grams = np.array([m.T @ m for m in (np.random.default_rng(k).normal(size=(3, 4)) *
                                        [1, 1, 1, 0.01 if k < 4 else 1] for k in range(12))])  # fmt: skip
    chosen, c = select_conditioned(grams, 4)
    first = np.sqrt(np.linalg.cond(grams[:4].sum(axis=0)))
    assert c < first and len(set(chosen)) == 4


def test_charuco_corners_deprojected_with_depth() -> None:
    spec = CharucoSpec()
    k = Intrinsics(848, 480, 615.0, 615.0, 423.5, 239.5)
    R = axis_angle_to_matrix(np.array([0.25, -0.3, 0.1]))
    c_T_b = make_T(R, [-0.12, -0.08, 0.6])
    rgb, depth = render_charuco(spec, k, c_T_b)
    found = detect_charuco(rgb, depth, k, spec)
    truth = spec.points() @ c_T_b[:3, :3].T + c_T_b[:3, 3]
    seen = np.all(np.isfinite(found), axis=1)
    assert seen.sum() >= 20  # of 24 inner corners
    err = np.linalg.norm(found[seen] - truth[seen], axis=1)
    print(f"\nChArUco corners: {seen.sum()}/24 seen, error median {1e3 * np.median(err):.2f} mm,"
          f" max {1e3 * err.max():.2f} mm at 0.6 m")  # fmt: skip
    assert np.max(err) < 2e-3
    hidden = rgb.copy()
    hidden[:, : k.width // 2] = 128  # half the board hidden: the rest keeps its ids
    part = detect_charuco(hidden, depth, k, spec)
    ok = np.all(np.isfinite(part), axis=1)
    assert 0 < ok.sum() < seen.sum()
    assert np.max(np.linalg.norm(part[ok] - truth[ok], axis=1)) < 2e-3


@pytest.fixture
def sim_system(sim_drivers: tuple[str, str]) -> tuple[str, str]:
    """The driver package's shared simulated cell (tests/drivers/conftest.py)."""
    return sim_drivers


def arm0_joints(ep: str, prefix: str) -> Any:
    """arm0's joint angles now, from its joint states on the bus (rad)."""
    client = raw_session(ep)
    states = Inbox(client, f"{prefix}/arm0/joint_states")
    try:
        wait_for(states.bodies, 10.0, "arm0 joint states")
        return np.array(states.bodies()[-1]["q"], dtype=float)
    finally:
        states.close()
        client.close()


def test_a_long_slow_move_goes_as_legs_under_the_body_limit() -> None:
    """The wizard's failure: one slow move over most of a joint's range was one 6 MB body,
    which the driver refuses (its limit is 4 MiB)."""
    from planner.bus.session import MAX_PAYLOAD_BYTES
    from planner.service.collect import LEG_BYTES, legs, trajectory_body

    system = system_from_scenario(load_scenario(SCENARIO))
    q0, q1 = np.zeros(6), np.array([3.0, -1.2, 1.0, 0.5, -2.0, 0.7])

    def size(mv: Any) -> int:
        return len(trajectory_body(system, "arm0", "x" * 12, "collect-12345678", mv))

    whole = size(min_jerk_move(q0, q1, 0.2))  # 28 s at 500 Hz
    assert whole > MAX_PAYLOAD_BYTES  # the move as one body: refused by the driver
    points = legs(q0, q1, 0.2, size)
    # as few as fit (sample rounding may cost one more than the bytes alone say)
    assert np.ceil(whole / LEG_BYTES) <= len(points) <= np.ceil(whole / LEG_BYTES) + 1
    starts = [q0, *points[:-1]]
    for a, b in zip(starts, points, strict=True):
        assert size(min_jerk_move(a, b, 0.2)) <= LEG_BYTES
        # every waypoint on the straight joint-space line of the move, in order
        s = float(np.dot(b - q0, q1 - q0) / np.dot(q1 - q0, q1 - q0))
        np.testing.assert_allclose(b, q0 + s * (q1 - q0), atol=1e-12)
    np.testing.assert_array_equal(points[-1], q1)
    assert legs(q0, 0.1 * q1, 0.2, size) == [pytest.approx(0.1 * q1)]  # a short move: one leg


@pytest.mark.serial
def test_a_move_in_legs_arrives_on_the_simulated_driver(sim_system: Any) -> None:
    """Each leg starts from rest where the last one ended: the real sim driver accepts every
    one, and the arm ends on the target."""
    from planner.bus.session import Keys
    from planner.safety.geometry import SafetyWorld
    from planner.service.collect import BusPlanner, trajectory_body

    ep, prefix = sim_system
    system = system_from_scenario(load_scenario(SCENARIO))
    client = raw_session(ep)
    statuses = Inbox(client, f"{prefix}/arm0/status")
    bp = BusPlanner(client, Keys(prefix), system)
    try:
        q0 = bp.wait_joints()["arm0"].copy()
        target = q0 + np.array([0.5, 0.0, 0.0, 0.0, 0.0, -0.5])

        def size(mv: Any) -> int:
            return len(trajectory_body(system, "arm0", "x" * 12, bp.name, mv))

        accel = bp._acceleration("arm0")
        whole = size(min_jerk_move(q0, target, 1.0, acceleration=accel))
        shortest = size(min_jerk_move(q0, q0 + 1e-3 * (target - q0), 1.0, acceleration=accel))
        bp.leg_bytes = (whole + shortest) // 2  # the move as one body is over it
        assert shortest < bp.leg_bytes < whole
        for goal in (target, q0):  # there and back: the cell is left as it was found
            assert bp.move("arm0", goal, 1.0, SafetyWorld(system, [])) is None
            np.testing.assert_allclose(bp.q["arm0"], goal, atol=2e-3)
    finally:
        bp.close()
        judged = {}
        for body in statuses.bodies():
            ack = body.get("trajectory") if isinstance(body, dict) else None
            if ack is not None:
                judged[ack["id"]] = ack["accepted"]
        statuses.close()
        client.close()
    # the move over the limit: 2+ legs each way, each accepted
    assert len(judged) >= 4 and all(judged.values()), judged


@pytest.mark.serial
def test_a_collection_sent_sigterm_mid_move_exits_at_once_and_the_arm_brakes(
    sim_system: Any, tmp_path: Path
) -> None:
    """The wizard's Cancel and a closing console send SIGTERM: the collector exits as on
    Ctrl-C (130, no dataset), its heartbeat stops and the driver brakes the moving arm."""
    from planner.bus.session import Keys
    from planner.safety.geometry import SafetyWorld
    from planner.service.collect import BusPlanner

    ep, prefix = sim_system
    out = tmp_path / "handeye.json"
    client = raw_session(ep)
    states = Inbox(client, f"{prefix}/arm0/joint_states")
    statuses = Inbox(client, f"{prefix}/arm0/status")
    system = system_from_scenario(load_scenario(SCENARIO))
    proc, back = None, None
    try:
        wait_for(states.bodies, 10.0, "arm0 joint states")
        q_start = np.array(states.bodies()[-1]["q"])
        proc = subprocess.Popen([*CLI, "calibrate", "collect", "handeye", "-s", str(SCENARIO),
                                 "-o", str(out), "--poses", "3", "--speed", "1.0", "--endpoint",
                                 ep, "--prefix", prefix], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, env=ENV)  # fmt: skip

        def moved() -> float:
            return float(np.max(np.abs(np.array(states.bodies()[-1]["q"]) - q_start)))

        wait_for(lambda: moved() > 0.05, 120.0, "the collection moving the arm")
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(10)
        exited = time.monotonic() - t0

        def at_rest() -> bool:
            return float(np.max(np.abs(states.bodies()[-1]["qd"]))) < 1e-3

        wait_for(at_rest, 2.0, "the arm at rest")
        rest = time.monotonic() - t0
        text = proc.stdout.read().decode() if proc.stdout else ""
        print(f"\nSIGTERM mid-move: the collector exited {exited:.2f} s after it (code {code}), "
              f"the arm was at rest {rest:.2f} s after it, {1e3 * moved():.0f} mrad from its start")  # fmt: skip
        assert code == 130 and "interrupted: the arm brakes" in text and not out.exists(), text
        assert exited < 3.0
        # the driver stopped it for the collector's going: its beats (the bus of up, with a
        # planner's token alive) or its planner token (here the only one) lost
        faults = {b.get("fault") or "" for b in statuses.bodies() if isinstance(b, dict)}
        assert "planner liveliness lost" in faults or any(
            f.startswith("planner heartbeat lost: session collect-") for f in faults
        ), faults
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc is not None:  # the cell as it was found
            bp = BusPlanner(client, Keys(prefix), system)
            try:
                back = bp.move("arm0", q_start, 1.0, SafetyWorld(system, []))
            finally:
                bp.close()
        statuses.close()
        states.close()
        client.close()
    assert back is None


@pytest.mark.serial
def test_collect_beam_on_the_simulated_system(sim_system: Any, tmp_path: Path) -> None:
    ep, prefix = sim_system
    system = system_from_scenario(load_scenario(SCENARIO))
    aim = np.array([-0.492, -0.55, -0.06])  # the top of the scenario's board (0.3 m square)
    out = tmp_path / "beam.json"
    run = subprocess.run([*CLI, "calibrate", "collect", "beam", "-s", str(SCENARIO), "-o",
                          str(out), "--aim", ",".join(f"{x:.4f}" for x in aim), "--poses", "4",
                          "--speed", "1.0", "--endpoint", ep, "--prefix", prefix],
                         capture_output=True, env=ENV, timeout=300)  # fmt: skip
    text = run.stdout.decode()
    summary = json.loads(text.strip().splitlines()[-1])
    assert "condition number of the beam Jacobian" in text
    assert run.returncode == 0 and summary["collected"] >= 3, text
    data = load_beam(out, system)
    assert len(data.q) == summary["collected"] and data.camera_spots == len(data.q)
    assert np.all(np.abs(data.spots_world[:, 2] + 0.06) < 3e-3)  # on the board's top face
    assert np.all(np.abs(data.spots_world[:, :2] - aim[:2]) < 0.15)


@pytest.mark.serial
def test_collect_user_mistakes_and_a_hostile_marker_query(sim_system: Any) -> None:
    ep, prefix = sim_system
    for args in (["handeye", "-s", "nope.yaml", "-o", "x.json"],
                 ["handeye", "-s", str(SCENARIO), "-o", "x.json", "--poses", "1"],
                 ["handeye", "-s", str(SCENARIO), "-o", "x.txt"],
                 ["handeye", "-s", str(SCENARIO), "-o", "x.json", "--robot", "arm9"],
                 ["beam", "-s", str(SCENARIO), "-o", "x.json", "--aim", "1,2"]):  # fmt: skip
        cli_run.assert_usage_error(cli_run.beamrelay("calibrate", "collect", *args))
    client = raw_session(ep)
    try:
        end = time.monotonic() + 10.0  # let the client discover the camera peer
        while not list(client.get(f"{prefix}/camera/markers", timeout=1.0)):
            assert time.monotonic() < end, "no camera answers markers queries"
        for body in (b"", b"garbage", b'{"board_points": "x"}', b'{"board_points": [[0,0,0]]}'):
            replies = list(client.get(f"{prefix}/camera/markers", payload=body, timeout=5.0))
            assert replies and "error" in json.loads(replies[0].ok.payload.to_bytes())
    finally:
        client.close()


def _gated(tmp: Path, aim: bool) -> Path:
    """paper_n1 with its laser gated by arm0's output 0 (and the aiming beam on output 1)."""
    text = SCENARIO.read_text()
    head = "rpy_deg: [40, 0, 0]}\n"
    extra = "    gate: {robot: arm0, output: 0}\n" + (
        "    aim: {robot: arm0, output: 1}\n" if aim else ""
    )
    assert head in text
    out = tmp / ("aimed.yaml" if aim else "gated.yaml")
    out.write_text(
        text.replace(head, head + extra, 1).replace("meshes/", str(SCENARIO.parent) + "/meshes/")
    )
    return out


def test_collect_beam_with_a_gate_but_no_aiming_beam_is_refused(tmp_path: Path) -> None:
    scn = _gated(tmp_path, aim=False)
    r = cli_run.beamrelay("calibrate", "collect", "beam", "-s", scn, "-o", tmp_path / "b.json",
                          "--aim", "-0.49,-0.55,-0.06")  # fmt: skip
    cli_run.assert_usage_error(r, "laser.aim")
    assert not (tmp_path / "b.json").exists()


@pytest.mark.serial
def test_collect_beam_reads_spots_under_the_aiming_beam_only(tmp_path: Path) -> None:
    scn = _gated(tmp_path, aim=True)
    ep, prefix = f"tcp/127.0.0.1:{free_port()}", "braim"
    bus = ["--scenario", str(scn), "--endpoint", ep, "--prefix", prefix]
    procs = [subprocess.Popen([*CLI, "driver", "robot", "--name", "arm0", "--listen", *bus],
                              stderr=subprocess.DEVNULL, env=ENV),
             subprocess.Popen([*CLI, "driver", "camera", "--stride", "8", "--seed", "3", *bus],
                              stderr=subprocess.DEVNULL, env=ENV)]  # fmt: skip
    states: list[dict[str, Any]] = []
    try:
        wait_for_nodes(ep, prefix, ("arm0", "camera"))
        client = raw_session(ep)
        sub = client.declare_subscriber(
            f"{prefix}/laser", lambda s: states.append(json.loads(s.payload.to_bytes()))
        )
        out = tmp_path / "beam.json"
        run = subprocess.run([*CLI, "calibrate", "collect", "beam", "-s", str(scn), "-o",
                              str(out), "--aim", "-0.492,-0.55,-0.06", "--poses", "3",
                              "--speed", "1.0", "--endpoint", ep, "--prefix", prefix],
                             capture_output=True, env=ENV, timeout=300)  # fmt: skip
        sub.undeclare()
        client.close()
    finally:
        for p in procs:
            p.terminate()
            p.wait(30)
    text = run.stdout.decode()
    assert run.returncode == 0, text + run.stderr.decode()
    summary = json.loads(text.strip().splitlines()[-1])
    print(f"collected {summary['collected']}; laser states {[(m['on'], m['aim']) for m in states]}")
    assert summary["collected"] >= 3
    assert not any(m["on"] for m in states)  # the treatment gate never opened
    assert sum(1 for m in states if m["aim"] and m["reason"] == "aim interval") >= 3


class BrakingWorld(SegmentWorld):
    """A clear world whose driver brakes the ``brakes``-th move halfway with ``why``."""

    def __init__(self, why: str, brakes: int, rests: bool = True) -> None:
        super().__init__(0.0, set())
        self.why, self.brakes, self.rests, self.calls = why, brakes, rests, 0
        self.robot = "arm0"

    def wait_joints(self) -> dict[str, Any]:
        return {"arm0": pose(self.q)}

    def move(self, robot: str, target: Any, speed: float, world: Any) -> Why | None:
        self.calls += 1
        if self.calls == self.brakes:
            self.q = (self.q + float(target[0])) / 2  # stopped on the way
            head, reason = self.why.split(": ", 1)  # as BusPlanner reads a driver's verdict
            return Why.driver(head, reason)
        return super().move(robot, target, speed, world)

    def wait_rest(self, robot: str) -> bool:
        return self.rests


@pytest.mark.parametrize(
    ("why", "rests", "collected"),
    [("driver braking: no planner alive (watchdog)", True, 3),
     ("refused by the driver: no heartbeat from planner session p-1 within 100 ms (last: "
      "130 ms ago)", True, 3),
     ("driver braking: planner heartbeat lost: session p-1 quiet 0.12 s", True, 3),
     ("driver braking: no planner alive (watchdog)", False, 2),  # never rests: not again
     ("driver stopped: stop requested on beamrelay/stop", True, 1),  # the operator's STOP
     ("driver fault: protective stop", True, 2)],
)  # fmt: skip
def test_a_move_braked_on_late_heartbeats_is_made_once_more(
    capsys: pytest.CaptureFixture[str], why: str, rests: bool, collected: int
) -> None:
    """On a loaded machine a driver may brake a collection's move because heartbeats came
    late; that pose is moved to once more from where the arm rests. A fault is never
    retried, and the return is then not attempted; after an operator's STOP the arm moves
    no more (no further pose, no return)."""
    from types import SimpleNamespace

    from planner.cli.collect import _visit

    bp = BrakingWorld(why, brakes=2, rests=rests)
    system = SimpleNamespace(robot=lambda name: SimpleNamespace(home=pose(0)))
    got_q, _, log = _visit(bp, system, "arm0", [pose(1), pose(2), pose(3)], 1.0, None,
                           lambda b: np.ones(3))  # fmt: skip
    assert len(got_q) == collected
    out = capsys.readouterr().out
    again = collected == 3
    assert ("once more" in out) == again, out
    assert log[1] == ("pose 2/3: ok" if again else f"pose 2/3: skipped ({why})")
    assert ("\nreturned to the start pose" in out) == again, out
    if "stop requested" in why:
        assert len(log) == 2 and bp.moves == [0.0, 1.0] and "no further pose" in out
