"""The live cloud the planner keeps for camera-frame targets (:mod:`planner.service.live_cloud`):
the newest sample kept undecoded, decoded on demand into the world around the targets;
a stale, malformed or hostile sample is no surface and never raises."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np

from planner.model.transforms import axis_angle_to_matrix, make_T
from planner.service.live_cloud import LiveCloud
from schemas.points import points_metadata
from tests.drivers.conftest import wait_for
from tests.fake_clock import FakeClock

WORLD_T_CAMERA = make_T(axis_angle_to_matrix([0.2, -0.4, 0.1]), [-1.0, -1.0, 0.5])


class Bytes:
    """What a Zenoh sample's payload and attachment offer: ``to_bytes()``."""

    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


def sample(points: np.ndarray, attachment: bytes | None = None) -> SimpleNamespace:
    pts = np.asarray(points, dtype=np.float32)
    meta = json.dumps(points_metadata(pts, 1.0, 7, {})).encode()
    return SimpleNamespace(payload=Bytes(pts.tobytes()),
                           attachment=Bytes(meta if attachment is None else attachment))  # fmt: skip


def test_the_cloud_around_the_targets_in_the_world() -> None:
    rng = np.random.default_rng(1)
    cam = rng.uniform([-0.2, -0.2, 0.7], [0.2, 0.2, 1.0], (20_000, 3))
    cam[::97] = np.nan  # holes in the depth image
    clock = FakeClock(100.0)
    cloud = LiveCloud(clock=clock)
    assert cloud.around(np.zeros(3), WORLD_T_CAMERA) is None  # nothing came yet
    cloud.callback(sample(cam))
    world = cam @ WORLD_T_CAMERA[:3, :3].T + WORLD_T_CAMERA[:3, 3]
    targets = world[[5, 4000]]  # two of its points (not holes)
    got = cloud.around(targets, WORLD_T_CAMERA, radius=0.02)
    assert got is not None and len(got) > 10
    ok = np.all(np.isfinite(world), axis=1)
    d = np.min(np.linalg.norm(world[ok][:, None] - targets[None], axis=2), axis=1)
    want = world[ok][d <= 0.02]  # the independent selection
    assert len(got) == len(want)
    np.testing.assert_allclose(np.sort(got, axis=0), np.sort(want, axis=0), atol=1e-6)
    clock.advance(1.01)  # older than a second: the scene may have moved
    assert cloud.around(targets, WORLD_T_CAMERA) is None


def test_a_bad_cloud_is_no_surface() -> None:
    cloud = LiveCloud(clock=FakeClock(0.0))
    pts = np.zeros((10, 3))
    for bad in (sample(pts, b"\xff"), sample(pts, b'{"schema": "x"}'),
                SimpleNamespace(payload=Bytes(b"abc"), attachment=sample(pts).attachment),
                SimpleNamespace(payload=Bytes(b""), attachment=None)):  # fmt: skip
        cloud.callback(bad)
        assert cloud.around(np.zeros(3), WORLD_T_CAMERA) is None


def test_the_node_lands_a_camera_target_on_the_live_cloud(tmp_path, node_rig) -> None:  # type: ignore[no-untyped-def]
    """A scenario without a scene: the camera's cloud of a flat surface (published on the
    bus as a camera driver does) carries a camera-frame target picked 5 mm off it; planned
    onto the plane the cloud shows, reported as landed on the camera cloud. A world-frame
    target and a request once the cloud is stale stay where they were asked."""
    from planner.service.handler import handler_from_scenario
    from tests.planner.raw_zenoh import ask
    from tests.planner.service.fake_driver import PREFIX
    from tests.test_e2e import SCENARIO

    text = SCENARIO.replace(SCENARIO[SCENARIO.index("scene:") : SCENARIO.index("targets:")], "")
    path = tmp_path / "bare.yaml"
    path.write_text(text)
    handler = handler_from_scenario(path)
    node, client, _ = node_rig(handler, handler.system.home)
    T = handler.system.world_T_camera()
    cam_T = np.linalg.inv(T)
    goal = np.array([-0.54, -0.57, -0.06])  # on the surface z = -0.06
    rng = np.random.default_rng(2)
    u = np.arange(-0.03, 0.0301, 0.0015)
    x, y = np.meshgrid(u, u)
    world = np.column_stack([goal[0] + x.ravel(), goal[1] + y.ravel(), np.full(x.size, goal[2])])
    world[:, 2] += rng.normal(0.0, 0.0005, len(world))
    cam = world @ cam_T[:3, :3].T + cam_T[:3, 3]
    pts = cam.astype(np.float32)
    meta = json.dumps(points_metadata(pts, 0.0, 1, {})).encode()
    picked = goal + np.array([0.0, 0.0, -0.005])  # the pick's depth 5 mm off

    def plan(frame: str) -> dict:  # type: ignore[type-arg]
        p = picked if frame == "world" else cam_T[:3, :3] @ picked + cam_T[:3, 3]
        body = {"schema": "beamrelay.request/1", "id": f"c-{frame}", "frame": frame,
                "points": [p.tolist()]}  # fmt: skip
        ok, reply = ask(client, f"{PREFIX}/plan", json.dumps(body).encode())
        assert ok, reply
        return json.loads(reply)  # type: ignore[no-any-return]

    client.put(f"{PREFIX}/camera/points", pts.tobytes(), attachment=meta)
    wait_for(lambda: node.cloud.around(goal[None], T) is not None, 5.0, "the node's cloud")
    doc = plan("camera")
    sol, tgt = doc["solutions"][0], doc["targets"][0]
    assert sol["status"] == "ok" and sol["surface"]["object"] == "camera cloud"
    assert abs(tgt["p"][2] - goal[2]) < 3e-4  # on the plane, not at the pick's depth
    assert "surface" not in plan("world")["solutions"][0]
    node.cloud.max_age = 0.0  # stale: no surface
    stale = plan("camera")
    assert "surface" not in stale["solutions"][0]
    np.testing.assert_allclose(stale["targets"][0]["p"], picked, atol=1e-9)
