"""The plan picture shows the scene objects, the keep-out volumes and the failed targets."""

from __future__ import annotations

import itertools
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from planner.plot_scene import draw_failed, draw_volumes


def test_box_edges_sphere_and_labels() -> None:
    fig = plt.figure()
    ax = fig.add_subplot(projection="3d")
    items = [{"name": "board", "box": [0.3, 0.2, 0.1], "world_T_object": {"xyz": [1, 2, 3]}},
             {"name": "eye", "sphere": 0.016, "world_T_object": {"xyz": [0, 0, 1]}}]  # fmt: skip
    drawn = draw_volumes(ax, items, "red", "keep-out")
    corners = {tuple(np.round(np.array([1, 2, 3]) + np.array(s) * [0.15, 0.1, 0.05], 9))
               for s in itertools.product((-1, 1), repeat=3)}  # fmt: skip
    edges = [d for d in drawn if d.shape == (2, 3)]
    assert len(edges) == 12
    assert {tuple(np.round(p, 9)) for e in edges for p in e} == corners
    for a, b in edges:  # every edge is parallel to one box axis
        assert np.count_nonzero(np.abs(b - a) > 1e-12) == 1
    sphere = next(d for d in drawn if d.shape[0] > 2)
    np.testing.assert_allclose(np.linalg.norm(sphere - [0, 0, 1], axis=1), 0.016, atol=1e-12)
    assert "keep-out" in [t.get_label() for t in ax.get_lines()]
    plt.close(fig)


def test_failed_targets_by_reason() -> None:
    fig = plt.figure()
    ax = fig.add_subplot(projection="3d")
    points = np.arange(15.0).reshape(5, 3)
    plan = {"solutions": [
        {"target": 0, "status": "ok"}, {"target": 1, "status": "failed", "reason": "keep_out"},
        {"target": 2, "status": "failed", "reason": "keep_out"},
        {"target": 3, "status": "failed", "reason": "collision"}, {"target": 4, "status": "ok"},
    ]}  # fmt: skip
    drawn = draw_failed(ax, plan, points)
    np.testing.assert_array_equal(drawn[0], points[[1, 2, 3]])
    labels = sorted(c.get_label() for c in ax.collections)
    assert labels == ["failed: collision (1)", "failed: keep_out (2)"]
    assert draw_failed(ax, {"solutions": [plan["solutions"][0]]}, points) == []
    plt.close(fig)


def test_plan_picture_of_the_face(tmp_path: Path) -> None:
    from planner.plan.pipeline import run_scenario
    from planner.plot import plot_plan
    from tests.paths import REPO

    out = run_scenario(REPO / "scenarios" / "face_keepout.yaml", progress=False)
    png = tmp_path / "face.png"
    plot_plan(out.system, out.targets, out.doc, png)
    assert png.stat().st_size > 30_000


def test_camera_frustum_from_the_intrinsics() -> None:
    from planner.plot_scene import draw_camera

    fig = plt.figure()
    ax = fig.add_subplot(projection="3d")
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90 deg about z
    T[:3, 3] = [0.5, -0.2, 1.0]
    drawn = draw_camera(ax, T, fx=400.0, fy=200.0, width=800, height=400, depth=0.1)
    np.testing.assert_allclose(drawn[0], [0.5, -0.2, 1.0])
    # a corner of the image, (u, v) = (width, height), back-projected 0.1 m ahead by hand
    x, y = 0.1 * (800 - 400) / 400, 0.1 * (400 - 200) / 200
    corner = np.array([0.5 - y, -0.2 + x, 1.1])
    assert np.min(np.linalg.norm(drawn[1:] - corner, axis=1)) < 1e-12
    assert "camera" in [c.get_label() for c in ax.collections]
    plt.close(fig)


def test_targets_are_drawn_large_enough_to_see() -> None:
    from planner.plot_scene import target_marker_size

    assert target_marker_size(1) == 60.0 and target_marker_size(10_000) == 6.0
    assert 6.0 < target_marker_size(100) < 60.0
