"""RealSense backend through the real SDK without hardware: record the simulated scene with
``rs.software_device`` + ``rs.recorder``, play it back, compare with the known geometry."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.camera.node import CameraNode, decode_points
from drivers.camera.realsense import DEPTH_UNIT, RealSenseCamera, detect_red_spot, write_recording
from drivers.camera.sim import build_scene, render_depth
from planner.bus.session import Keys, decode, open_session
from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
from schemas.messages import SpotMessage
from tests.drivers.conftest import wait_for
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "paper_n1.yaml"
SPOT_UV = (431, 305)  # px: where the red spot is drawn (on the board)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any, np.ndarray]:
    scn = load_scenario(SCENARIO)
    system = system_from_scenario(scn, truth=True)
    cam = system.camera
    assert cam is not None
    k = cam.intrinsics
    z, _ = render_depth(build_scene(scene_objects(scn)), cam, stride=1)
    depth = z.reshape(k.height, k.width)
    rgb = np.zeros((k.height, k.width, 3), np.uint8)
    rgb[np.isfinite(depth)] = (120, 120, 120)  # grey board on black
    vv, uu = np.mgrid[0 : k.height, 0 : k.width]
    disk = (uu - SPOT_UV[0]) ** 2 + (vv - SPOT_UV[1]) ** 2 <= 9
    rgb[disk] = (255, 40, 40)
    assert np.isfinite(depth[SPOT_UV[1], SPOT_UV[0]])
    path = tmp_path_factory.mktemp("rs") / "scene.db3"
    write_recording(path, [depth] * 4, [rgb] * 4, k)
    return path, cam, depth


def test_detect_red_spot_centroid() -> None:
    img = np.zeros((60, 80, 3), np.uint8)
    img[20:23, 30:34] = (250, 10, 10)  # 3 x 4 block: centroid (31.5, 21)
    img[50, 70] = (120, 0, 0)  # a weaker red pixel elsewhere
    found = detect_red_spot(img)
    assert found is not None
    assert found[0] == pytest.approx((31.5, 21.0)) and found[1] == 240
    assert detect_red_spot(np.full((10, 10, 3), 200, np.uint8)) is None  # white is not red


def test_playback_cloud_and_spot_match_the_scene(recording: tuple[Path, Any, np.ndarray]) -> None:
    path, cam, depth = recording
    k = cam.intrinsics
    src = RealSenseCamera(file=path, realtime=False)
    try:
        src.grab()
        assert src.intrinsics() == k
        pts, meta = src.points()
        ok = np.isfinite(depth) & (depth > 0)
        assert pts.shape == (int(ok.sum()), 6) and meta["width"] == 848
        # expected points: pixel rays scaled by the (1 mm quantised) depth, pixel centres
        vv, uu = np.nonzero(ok)
        zq = np.round(depth[ok] / DEPTH_UNIT) * DEPTH_UNIT
        expected = np.column_stack([(uu - k.cx) / k.fx * zq, (vv - k.cy) / k.fy * zq, zq])
        np.testing.assert_allclose(pts[:, :3], expected, atol=1e-5)
        grey = pts[:, 3] >= 120 / 255 - 1e-6  # textured by the grey board (or the red spot)
        assert grey.mean() > 0.98  # (texture lookups at the board edge may land off it)

        spot = src.spot()
        assert spot is not None
        u, v = SPOT_UV
        z_true = depth[v, u]
        truth = np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0]) * z_true
        assert np.linalg.norm(spot.p_camera - truth) < 1e-3
        # ungated (no gate information): confidence halved; the full window has depth
        assert spot.confidence == pytest.approx(0.5 * 215 / 255, abs=1e-6)
    finally:
        src.close()


def test_camera_node_publishes_recording(
    recording: tuple[Path, Any, np.ndarray], hub: Any, endpoint: str, keys: Keys
) -> None:
    path, cam, depth = recording
    got: dict[str, list[Any]] = {"spot": [], "pts": []}
    subs = [
        hub.declare_subscriber(keys.camera_spot, got["spot"].append),
        hub.declare_subscriber(keys.camera_points, got["pts"].append),
    ]
    session = open_session(listen=False, endpoint=endpoint)
    node = CameraNode(session, keys, RealSenseCamera(file=path), spot_rate=30, points_rate=15)
    node.start()
    try:
        wait_for(lambda: len(got["pts"]) >= 2 and len(got["spot"]) >= 4, what="camera messages")
        spot = decode(got["spot"][-1].payload.to_bytes(), SpotMessage)
        assert spot.p_camera is not None
        u, v = SPOT_UV
        k = cam.intrinsics
        assert spot.p_camera[2] == pytest.approx(depth[v, u], abs=1e-3)
        assert spot.p_camera[0] == pytest.approx((u - k.cx) / k.fx * depth[v, u], abs=1e-3)
        pts, meta = decode_points(
            got["pts"][-1].payload.to_bytes(), got["pts"][-1].attachment.to_bytes()
        )
        assert meta["fields"] == ["x", "y", "z", "r", "g", "b"]
        assert pts.shape[0] == int(np.isfinite(depth).sum())
    finally:
        node.stop()
        session.close()
        for s in subs:
            s.undeclare()
