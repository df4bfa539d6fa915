"""Camera-frame requests through the node's request handler when the real camera is a few mm
off its calibrated pose: the board points it saw land on the board (the plan passes the
``beamrelay check`` re-verification and the plan.json schema), the same points as world
targets stay occluded, a keep-out volume at the landing point refuses the target, and the
closed-loop rows of a camera-frame request are given in the camera frame."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.io.plan_reports import ClosedLoopTarget, ServoFigures
from planner.model.status import ServoStatus
from planner.model.transforms import axis_angle_to_matrix, inv_T, make_T, transform_points
from planner.service.closed_loop import in_camera_frame
from planner.service.handler import RequestHandler, handler_from_scenario
from planner.verify.check import check_plan
from schemas.messages import TargetRequest
from schemas.plan import Plan
from tests.test_camera_frame_e2e import CAMERA_ERROR
from tests.test_closed_loop_tilted_e2e import CENTRE, NORMAL, TILTED, tilted_targets

TOP = CENTRE + 0.005 * NORMAL
ERROR = CAMERA_ERROR  # 6 mm, 1 deg (camera frame): the points map behind the board


def request(points: np.ndarray, normal: np.ndarray, frame: str) -> TargetRequest:
    return TargetRequest.model_validate({
        "schema": "beamrelay.request/1", "id": "t", "frame": frame, "points": points.tolist(),
        "normals": [normal.tolist()] * len(points),
    })  # fmt: skip


def setup(tmp_path: Path, extra: str = "") -> tuple[RequestHandler, np.ndarray, np.ndarray]:
    """The handler of the tilted cell and two board points (camera frame) as a camera
    displaced by :data:`ERROR` from the calibrated pose sees them, and their normal."""
    path = tmp_path / "tilted.yaml"
    path.write_text(TILTED + extra)
    handler = handler_from_scenario(path)
    true_T = handler.system.world_T_camera() @ ERROR
    camera_T_world = inv_T(true_T)
    return handler, transform_points(camera_T_world, tilted_targets(2, seed=3)), camera_T_world[:3, :3] @ NORMAL  # fmt: skip


def plan(handler: RequestHandler, req: TargetRequest) -> dict[str, Any]:
    return handler.plan_fn(handler.targets(req), None, False).to_document()


def test_camera_targets_land_on_their_board_and_world_ones_stay_occluded(tmp_path: Path) -> None:
    handler, p_cam, n_cam = setup(tmp_path)
    doc = plan(handler, request(p_cam, n_cam, "camera"))
    assert [s["status"] for s in doc["solutions"]] == ["ok", "ok"]
    mapped = transform_points(handler.system.world_T_camera(), p_cam)
    for tgt, sol, requested in zip(doc["targets"], doc["solutions"], mapped, strict=True):
        assert abs(NORMAL @ (np.asarray(tgt["p"]) - TOP)) < 1e-5  # on the board's top face
        assert NORMAL @ (requested - TOP) < -1e-3  # the camera's point lay behind it
        assert sol["surface"]["object"] == "board"
        np.testing.assert_allclose(sol["surface"]["requested"], requested, atol=1e-12)
        assert sol["error"] < 1e-9
    Plan.model_validate(doc)  # the additive ``surface`` key is part of the schema
    assert not [f for r in check_plan(doc) for f in r.findings]
    world = plan(handler, request(mapped, handler.system.world_T_camera()[:3, :3] @ n_cam,
                                  "world"))  # fmt: skip
    assert [s["reason"] for s in world["solutions"]] == ["occluded", "occluded"]


def test_a_keep_out_volume_at_the_landing_point_refuses_the_target(tmp_path: Path) -> None:
    handler, p_cam, n_cam = setup(tmp_path)
    landed = plan(handler, request(p_cam, n_cam, "camera"))["targets"][0]["p"]
    xyz = ", ".join(f"{x:.6f}" for x in landed)
    eye = f"keep_out:\n  - {{name: eye, sphere: 0.004, world_T_object: {{xyz: [{xyz}]}}}}\n"
    guarded, _, _ = setup(tmp_path, eye)
    doc = plan(guarded, request(p_cam, n_cam, "camera"))
    assert [s["reason"] for s in doc["solutions"]] == ["keep_out", None]


def test_closed_loop_rows_of_a_camera_request_are_in_the_camera_frame() -> None:
    world_T_camera = make_T(axis_angle_to_matrix([0.3, -0.2, 0.1]), [-1.0, -1.0, 0.5])
    p_cam = np.array([[0.01, 0.02, 0.8], [0.0, -0.03, 0.9]])
    spot_cam = p_cam[0] + [2e-4, -1e-4, 0.0]

    def row(k: int, status: ServoStatus, spot: np.ndarray | None) -> ClosedLoopTarget:
        run = ServoFigures(1, 3, 0.1, 1e-3, None if spot is None else 1e-4,
                           np.array([1e-3, np.nan]), spot, {"arm0": np.zeros(6)})  # fmt: skip
        return ClosedLoopTarget(k, status, servo=run)

    spot_world = transform_points(world_T_camera, spot_cam)
    rows = in_camera_frame([row(0, ServoStatus.CONVERGED, spot_world),
                            row(1, ServoStatus.NOT_SEEN, None)], p_cam, world_T_camera)  # fmt: skip
    assert rows[0].spot_camera is not None and rows[0].error_camera is not None
    np.testing.assert_allclose(rows[0].spot_camera, spot_cam, atol=1e-12)
    assert rows[0].error_camera == pytest.approx(np.sqrt(5e-8), rel=1e-9)
    doc = rows[1].to_document()
    assert doc["target_camera"] == p_cam[1].tolist() and "measured_error_camera" not in doc


def test_a_scenarios_camera_frame_targets_land_on_their_board(tmp_path: Path) -> None:
    """``targets: {frame: camera}`` in a scenario file, planned by ``beamrelay plan`` (run
    in-process): the same landing as a request's, so the points the camera saw are planned
    on the board, not failed as occluded; world-frame copies stay occluded."""
    from tests.cli_run import beamrelay

    handler, p_cam, n_cam = setup(tmp_path)
    mapped = transform_points(handler.system.world_T_camera(), p_cam)

    def targets(frame: str, points: np.ndarray, normal: np.ndarray) -> str:
        rows = ", ".join("[" + ", ".join(f"{x:.9f}" for x in p) + "]" for p in points)
        n = "[" + ", ".join(f"{x:.9f}" for x in normal) + "]"
        return f"targets:\n  frame: {frame}\n  points: [{rows}]\n  normals: [{n}, {n}]\n"

    docs = {}
    for frame, points, normal in (("camera", p_cam, n_cam),
                                  ("world", mapped, handler.system.world_T_camera()[:3, :3] @ n_cam)):  # fmt: skip
        text = TILTED.replace(TILTED[TILTED.index("targets:"):TILTED.index("trajectory:")],
                              targets(frame, points, normal))  # fmt: skip
        path = tmp_path / f"{frame}.yaml"
        path.write_text(text)
        out = tmp_path / f"{frame}.json"
        ran = beamrelay("plan", path, "--out", out)
        assert ran.returncode == (0 if frame == "camera" else 1), ran.stderr  # 1: one failed
        docs[frame] = json.loads(out.read_text())
    doc = docs["camera"]
    assert [s["status"] for s in doc["solutions"]] == ["ok", "ok"]
    for tgt, sol, requested in zip(doc["targets"], doc["solutions"], mapped, strict=True):
        assert abs(NORMAL @ (np.asarray(tgt["p"]) - TOP)) < 1e-5
        np.testing.assert_allclose(sol["surface"]["requested"], requested, atol=1e-9)
        assert sol["surface"]["offset_m"] < 0  # the board lay before the mapped point
    assert [s["reason"] for s in docs["world"]["solutions"]] == ["occluded", "occluded"]


def test_a_camera_frame_path_is_swept_on_its_board(tmp_path: Path) -> None:
    """A path the camera saw across the board (a 40 mm line), sent in the camera frame: swept
    on the board's top face (every sample within 10 um of it, each landed sample's offset
    reported), where the same samples as world targets lie behind the board and are
    occluded."""
    handler, _, n_cam = setup(tmp_path)
    true_T = handler.system.world_T_camera() @ ERROR
    ends = TOP + np.array([[-0.02, 0.0, 0.0], [0.02, 0.0, 0.0]])  # on the true board
    p_cam = transform_points(inv_T(true_T), ends)
    req = TargetRequest.model_validate({
        "schema": "beamrelay.request/1", "id": "p", "frame": "camera", "mode": "path",
        "points": p_cam.tolist(), "normals": [n_cam.tolist()] * 2})  # fmt: skip
    doc = plan(handler, req)
    status = [s["status"] for s in doc["solutions"]]
    assert len(status) > 20 and set(status) == {"ok"}, status
    depth = [abs(float(NORMAL @ (np.asarray(t["p"]) - TOP))) for t in doc["targets"]]
    assert max(depth) < 1e-5, max(depth)
    offsets = [s["surface"]["offset_m"] for s in doc["solutions"] if "surface" in s]
    assert len(offsets) == len(status) and all(-0.015 < o < -1e-3 for o in offsets)
    assert all(s["error"] < 1e-6 for s in doc["solutions"])
    world = req.model_copy(update={"frame": "world"})
    mapped = handler.targets(req).points  # the samples as the calibrated pose maps them
    world_doc = plan(handler, world.model_copy(update={"points": mapped[[0, -1]].tolist(),
                     "normals": [(handler.system.world_T_camera()[:3, :3] @ n_cam).tolist()] * 2}))  # fmt: skip
    assert {s["reason"] for s in world_doc["solutions"]} == {"occluded"}
