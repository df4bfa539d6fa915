"""Driver processes as users start them: ``beamrelay driver robot|camera`` over a real bus."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from drivers.camera.node import decode_points
from planner.bus.session import Keys, decode
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.transforms import inv_T
from schemas.messages import JointState, SpotMessage
from tests import cli_run
from tests.drivers.camera.test_camera_sim import analytic_spot
from tests.drivers.conftest import wait_for
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "paper_n1.yaml"
CLI = [sys.executable, "-m", "planner.cli", "driver"]


def run(
    args: list[str], endpoint: str, prefix: str, scenario: Path = SCENARIO
) -> subprocess.Popen[bytes]:
    bus = ["--scenario", str(scenario), "--endpoint", endpoint, "--prefix", prefix]
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    return subprocess.Popen([*CLI, *args, *bus], stderr=subprocess.PIPE, env=env)


def test_robot_and_camera_drivers_publish_and_stop_on_sigterm(
    hub: Any, endpoint: str, keys: Keys
) -> None:
    got: dict[str, list[Any]] = {"js": [], "spot": [], "pts": []}
    subs = [
        hub.declare_subscriber(keys.joint_states("arm0"), got["js"].append),
        hub.declare_subscriber(keys.camera_spot, got["spot"].append),
        hub.declare_subscriber(keys.camera_points, got["pts"].append),
    ]
    robot = run(["robot", "--name", "arm0"], endpoint, keys.prefix)
    camera = run(["camera", "--stride", "4", "--seed", "1"], endpoint, keys.prefix)
    try:

        def last_spots() -> list[SpotMessage]:
            return [decode(s.payload.to_bytes(), SpotMessage) for s in got["spot"][-10:]]

        # the camera reports no spot until the robot's first joint state reaches it; the
        # order check below reads the last 200 joint states (a loaded machine may start the
        # camera's stream before the robot's has sent that many: 164 once)
        wait_for(
            lambda: (
                len(got["pts"]) > 3
                and len(got["js"]) >= 200
                and len(got["spot"]) >= 10
                and all(s.p_camera is not None for s in last_spots())
            ),
            timeout=30,
            what="camera: 10 spots in a row",
        )
        alive = {str(r.ok.key_expr) for r in hub.liveliness().get(keys.alive_all)}
        assert alive == {keys.alive("arm0"), keys.alive("camera")}
        js = decode(got["js"][-1].payload.to_bytes(), JointState)
        system = system_from_scenario(load_scenario(SCENARIO))
        np.testing.assert_allclose(js.q, system.robots[0].home, atol=1e-12)
        # the camera traced the beam at the published home pose: spot on the board
        truth = system_from_scenario(load_scenario(SCENARIO), truth=True)
        assert truth.camera is not None
        expected = inv_T(truth.camera.world_T_camera) @ np.append(analytic_spot(truth, js.q), 1)
        p = np.array([s.p_camera for s in last_spots() if s.p_camera is not None])
        assert len(p) == 10
        assert np.linalg.norm(p.mean(axis=0) - expected[:3]) < 5e-4
        last = got["pts"][-1]
        pts, meta = decode_points(last.payload.to_bytes(), last.attachment.to_bytes())
        assert meta["stride"] == 4 and pts.shape == (meta["count"], 3) and meta["count"] > 500
        w = (
            pts.astype(float) @ truth.camera.world_T_camera[:3, :3].T
            + truth.camera.world_T_camera[:3, 3]
        )
        assert np.median(np.abs(w[:, 2] + 0.06)) < 2e-3  # on the board's top face
        # rates over the last second of messages (by their own timestamps)
        t_js = np.array([decode(s.payload.to_bytes(), JointState).t for s in got["js"][-200:]])
        t_pts = np.array(
            [
                decode_points(s.payload.to_bytes(), s.attachment.to_bytes())[1]["t"]
                for s in got["pts"][-10:]
            ]
        )
        print(
            f"joint_states {1 / np.median(np.diff(t_js)):.0f} Hz, points {1 / np.median(np.diff(t_pts)):.1f} Hz"
        )
        # both stream, stamped in order (the rates are printed figures, not bounds: a loaded
        # CI machine raycasts the 15 Hz cloud slower)
        assert len(t_js) == 200 and np.all(np.diff(t_js) > 0) and np.all(np.diff(t_pts) > 0)
    finally:
        for proc in (robot, camera):
            proc.send_signal(signal.SIGTERM)
        codes = [proc.wait(timeout=10) for proc in (robot, camera)]
        for s in subs:
            s.undeclare()
    errs = [p.stderr.read().decode(errors="replace")[-3000:] if p.stderr else "" for p in
            (robot, camera)]  # fmt: skip
    assert codes == [0, 0], errs
    time.sleep(0.2)
    assert not list(hub.liveliness().get(keys.alive_all))  # tokens withdrawn


def test_user_mistakes_exit_2_with_one_line(endpoint: str) -> None:
    cases = [
        (["robot", "--name", "arm7"], "unknown robot 'arm7'"),
        # paper_n1 has no laser.gate: the real arm refuses to run an "always on" laser
        (["robot", "--name", "arm0", "--backend", "ur", "--host", "10.0.0.9"], "laser.gate"),
        (["robot", "--name", "arm0", "--backend", "ur", "@gated"], "--host"),
        (
            [
                "robot",
                "--name",
                "arm0",
                "--backend",
                "ur",
                "--host",
                "10.0.0.9",
                "--no-require-planner",
                "@gated",
            ],
            "--no-require-planner",
        ),
        (["robot", "--name", "arm0", "--state-rate", "50"], "--state-rate"),
        (["camera", "--stride", "0"], "--stride"),
    ]
    for args, needle in cases:
        gated = "@gated" in args
        args = [a for a in args if a != "@gated"]
        scenario = REPO / "scenarios" / "s_curve.yaml" if gated else SCENARIO
        bus = ["--scenario", scenario, "--endpoint", endpoint, "--prefix", "brbad"]
        cli_run.assert_usage_error(cli_run.beamrelay("driver", *args, *bus), needle)


def test_help_texts_name_the_real_recording_format_and_no_spec_sections() -> None:
    env = dict(os.environ, PYTHONPATH=os.getcwd(), COLUMNS="200")
    helps = {}
    for cmd in ([], ["robot"], ["camera"], ["bench"]):
        out = subprocess.run([*CLI, *cmd, "--help"], capture_output=True, env=env, timeout=60)
        assert out.returncode == 0, out.stderr
        helps[" ".join(cmd)] = out.stdout.decode()
    assert ".db3" in helps["camera"] and ".bag" not in helps["camera"]
    assert all("SPEC" not in text for text in helps.values())
    assert "heartbeat" in helps["robot"]


def test_bench_refuses_bad_values_with_one_line() -> None:
    for args, needle in [(["--samples", "1"], "--samples"), (["--samples", "20000"], "--samples"),
                         (["--rate", "0"], "--rate"), (["--seconds", "-1"], "--seconds")]:  # fmt: skip
        cli_run.assert_usage_error(cli_run.beamrelay("driver", "bench", *args), needle)


def child_pids(pid: int) -> set[int]:
    """Live children of ``pid`` (Linux /proc)."""
    out = set()
    for d in Path("/proc").iterdir():
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            if d.name.isdigit() and int(fields[1]) == pid and fields[0] != "Z":
                out.add(int(d.name))
        except (OSError, ValueError, IndexError):
            continue
    return out


def test_sigkilled_robot_driver_leaves_no_parse_worker_behind(
    hub: Any, endpoint: str, keys: Keys
) -> None:
    robot = run(["robot", "--name", "arm0"], endpoint, keys.prefix)
    try:
        wait_for(lambda: bool(list(hub.liveliness().get(keys.alive("arm0")))), 30, "driver up")
        kids = child_pids(robot.pid)
        assert kids, "the driver runs its parse worker in a child process"
    finally:
        robot.kill()
        robot.wait(10)
    wait_for(lambda: not any(Path(f"/proc/{k}").exists() for k in kids), 10, "workers gone")
