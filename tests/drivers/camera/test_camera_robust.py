"""A RealSense camera that misbehaves: incomplete framesets, timeouts, a dead device; frame
timestamps in messages; the gated spot through the real SDK path (recordings)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.camera.node import CameraNode
from drivers.camera.realsense import CameraLostError, RealSenseCamera, write_recording
from planner.bus.session import Keys, decode, open_session
from planner.model.system import Intrinsics
from schemas.messages import SpotMessage
from tests import cli_run
from tests.drivers.conftest import wait_for
from tests.paths import REPO

K = Intrinsics(160, 120, 150.0, 150.0, 79.5, 59.5)
T0_MS = 1.7e12  # a UNIX time in ms (2023-11)
SPOT_UV = (90.25, 50.5)


def board(n: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    depth = [np.full((K.height, K.width), 0.8) for _ in range(n)]
    rgb = [np.full((K.height, K.width, 3), 100, np.uint8) for _ in range(n)]
    for img in rgb:
        img[10:30, 10:30] = (220, 20, 20)  # a red object, always there
    return depth, rgb


def spot(img: np.ndarray) -> np.ndarray:
    vv, uu = np.mgrid[0 : K.height, 0 : K.width]
    g = np.exp(-((uu - SPOT_UV[0]) ** 2 + (vv - SPOT_UV[1]) ** 2) / (2 * 1.5**2))
    out = img.astype(float)
    out[..., 0] += 120 * g
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


class _Pipeline:
    """Stands in for rs.pipeline: every wait times out; counts restarts."""

    def __init__(self) -> None:
        self.starts = self.stops = 0

    def try_wait_for_frames(self, timeout_ms: int) -> tuple[bool, Any]:
        return False, None

    def stop(self) -> None:
        self.stops += 1

    def start(self, config: Any) -> Any:
        self.starts += 1
        raise RuntimeError("No device connected")


def test_timeouts_restart_then_camera_lost(tmp_path: Path) -> None:
    depth, rgb = board(2)
    write_recording(tmp_path / "a.db3", depth, rgb, K)
    cam = RealSenseCamera(file=tmp_path / "a.db3", realtime=False, reconnects=2)
    real = cam.pipeline
    try:
        fake = _Pipeline()
        fake.start = lambda config: None  # type: ignore[method-assign]
        cam.pipeline, cam.file = fake, None  # type: ignore[assignment]
        assert cam.grab() is False and cam.grab() is False  # two restarts
        assert cam.restarts == 2 and fake.stops == 2
        with pytest.raises(CameraLostError, match="2 pipeline restarts did not help"):
            cam.grab()
        dead = _Pipeline()
        cam.pipeline, cam._failed_restarts = dead, 0  # type: ignore[assignment]
        with pytest.raises(CameraLostError, match=r"restart failed: .*No device connected"):
            cam.grab()
    finally:
        real.stop()


def test_depth_only_camera_process_exits_nonzero(tmp_path: Path, endpoint: str) -> None:
    """Colour never arrives: the framesets are skipped, then the process says so and
    exits 1 (one line on stderr), so a supervisor sees it."""
    depth, _ = board(3)
    path = tmp_path / "depth_only.db3"
    write_recording(path, depth, None, K)
    scenario = REPO / "scenarios" / "paper_n1.yaml"
    cmd = [sys.executable, "-m", "planner.cli", "driver", "camera", "--backend", "realsense",
           "--file", str(path), "--frame-timeout", "0.3", "--scenario", str(scenario),
           "--endpoint", endpoint, "--listen", "--prefix", "brtest"]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    out = subprocess.run(cmd, capture_output=True, env=env, timeout=60)
    assert out.returncode == 1
    err = out.stderr.decode().strip().splitlines()
    assert err[-1].startswith("error: camera loop died: CameraLostError: no complete frameset")


def test_bad_frame_timeout_is_a_user_error(endpoint: str) -> None:
    out = cli_run.beamrelay("driver", "camera", "--backend", "realsense", "--frame-timeout", "nan",
                            "--scenario", REPO / "scenarios" / "paper_n1.yaml",
                            "--endpoint", endpoint)  # fmt: skip
    cli_run.assert_usage_error(out, "--frame-timeout")


def test_gated_spot_and_frame_times_through_the_sdk(
    tmp_path: Path, hub: Any, endpoint: str, keys: Keys
) -> None:
    """Frames 0-3 gate off, 4-7 gate on (the spot in them): the node publishes the gated
    spot (not the red object), stamped with the frames' capture times."""
    depth, rgb = board(8)
    rgb = [img if i < 4 else spot(img) for i, img in enumerate(rgb)]
    path = tmp_path / "gated.db3"
    write_recording(path, depth, rgb, K, t0_ms=T0_MS)
    times = [(T0_MS + i * 1000 / 30) / 1e3 for i in range(8)]
    src = RealSenseCamera(file=path, realtime=False)
    src.on_gate(False, times[0] - 1.0)
    src.on_gate(True, times[3] + 0.006)  # just after frame 3: frame 4 straddles the switch
    got: list[Any] = []
    sub = hub.declare_subscriber(keys.camera_spot, got.append)
    session = open_session(listen=False, endpoint=endpoint)
    node = CameraNode(session, keys, src, spot_rate=200, points_rate=1).start(loop=False)
    try:
        while node.frames < 8:
            node.publish_frame()
        wait_for(lambda: len(got) >= 8, what="spots")
        msgs = [decode(s.payload.to_bytes(), SpotMessage) for s in got[:8]]
        # each message carries its frame's capture time (playback may skip a first frame)
        index = [round((m.t * 1e3 - T0_MS) * 30 / 1e3) for m in msgs]
        assert [m.t for m in msgs] == pytest.approx([times[i] for i in index], abs=1e-6)
        assert len(set(index)) >= 6
        for i, m in zip(index, msgs, strict=True):
            assert (m.p_camera is not None) == (i >= 5), i  # off and straddling frames: none
        z = 0.8
        truth = [(SPOT_UV[0] - K.cx) / K.fx * z, (SPOT_UV[1] - K.cy) / K.fy * z, z]
        for m in msgs:
            if m.p_camera is not None:
                assert np.linalg.norm(np.subtract(m.p_camera, truth)) < 2e-4  # 0.2 mm
                assert m.confidence > 0.8
        assert time.time() - msgs[-1].t > 1e7  # 2023 stamps: clearly not the publish time
    finally:
        node.stop()
        session.close()
        sub.undeclare()
