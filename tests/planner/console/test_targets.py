"""The target list and the TargetRequest built from it (checked by the request schema)."""

from __future__ import annotations

import numpy as np
import pytest

from planner.bus.session import decode, encode
from planner.console.targets import Mode, TargetList, build_request, path_points
from planner.errors import InputError
from schemas.messages import TargetRequest

UP = np.array([0.0, 0.0, 1.0])


def three() -> TargetList:
    t = TargetList()
    for p in ([-0.50, -0.55, -0.06], [-0.48, -0.53, -0.06], [-0.46, -0.56, -0.06]):
        t = t.add(np.array(p), UP * 2.0)
    return t


def test_edits_return_new_lists_in_the_expected_order() -> None:
    t = three()
    xs = lambda tl: [round(p[0], 2) for p in tl.points()]  # noqa: E731
    assert xs(t) == [-0.50, -0.48, -0.46]
    assert xs(t.move(0, +1)) == [-0.48, -0.50, -0.46]
    assert xs(t.move(2, -5)) == [-0.46, -0.50, -0.48]  # clamped at the top
    assert xs(t.move(1, +9)) == [-0.50, -0.46, -0.48]
    assert xs(t.delete(1)) == [-0.50, -0.46]
    assert xs(t) == [-0.50, -0.48, -0.46]  # unchanged
    assert np.allclose(t.normals(), UP)  # normalised on add
    assert t.items[0].label(0) == "#0  -500.0, -550.0, -60.0 mm"
    with pytest.raises(InputError, match="no target #3"):
        t.delete(3)
    with pytest.raises(InputError, match="not finite"):
        t.add(np.array([np.nan, 0, 0]))


def test_points_request_validates_and_carries_the_flags() -> None:
    req = build_request(three(), Mode.POINTS, execute=True, closed_loop=True, dwell=0.4)
    parsed = decode(encode(req), TargetRequest)
    assert parsed.mode == "points" and parsed.execute and parsed.closed_loop
    assert parsed.dwell == 0.4
    assert np.allclose(parsed.points, three().points())
    assert np.allclose(parsed.normals, np.tile(UP, (3, 1)))
    no_n = build_request(three(), Mode.POINTS, use_normals=False)
    assert "normals" not in no_n and no_n["closed_loop"] is False


def test_a_target_without_normal_drops_all_normals() -> None:
    t = three().add(np.array([-0.5, -0.5, -0.06]))
    assert t.normals() is None
    assert "normals" not in build_request(t, Mode.POINTS)


def test_polyline_path_sends_the_vertices() -> None:
    req = build_request(three(), Mode.POLYLINE, dwell=1.0)
    parsed = decode(encode(req), TargetRequest)
    assert parsed.mode == "path" and parsed.dwell is None  # dwell is for point targets
    assert np.allclose(parsed.points, three().points())


def test_smooth_path_is_a_dense_spline_through_the_targets() -> None:
    P, N = path_points(three(), Mode.SMOOTH, spacing=0.001)
    V = three().points()
    step = np.linalg.norm(np.diff(P, axis=0), axis=1)
    assert step.max() <= 0.001 + 1e-9
    for v in V:  # passes through every clicked target
        assert np.min(np.linalg.norm(P - v, axis=1)) < 0.001
    assert np.allclose(P[0], V[0]) and np.allclose(P[-1], V[-1])
    assert N is not None and np.allclose(N, UP)
    decode(encode(build_request(three(), Mode.SMOOTH)), TargetRequest)


@pytest.mark.parametrize(
    ("targets", "mode", "dwell", "match"),
    [
        (TargetList(), Mode.POINTS, None, "no targets"),
        (TargetList().add(np.zeros(3)), Mode.POLYLINE, None, "path needs >= 2"),
        (TargetList().add(np.zeros(3)), Mode.POINTS, -1.0, "dwell"),
        (TargetList().add(np.zeros(3)), Mode.POINTS, float("nan"), "dwell"),
    ],
)
def test_bad_requests_are_input_errors(targets: TargetList, mode: Mode, dwell: float | None,
                                       match: str) -> None:  # fmt: skip
    with pytest.raises(InputError, match=match):
        build_request(targets, mode, dwell=dwell)


def test_picks_of_a_fixed_cameras_cloud_go_in_its_frame() -> None:
    """With the calibrated camera pose, the request carries the picks (and normals) where the
    camera saw them: mapped back through that pose they are the picks again."""
    from planner.model.transforms import inv_T, look_at

    world_T_camera = look_at([-1.0, -1.0, 0.5], three().points().mean(axis=0))
    for mode in (Mode.POINTS, Mode.POLYLINE):
        req = build_request(three(), mode, camera_T_world=inv_T(world_T_camera))
        parsed = decode(encode(req), TargetRequest)
        assert parsed.frame == "camera"
        back = np.asarray(parsed.points) @ world_T_camera[:3, :3].T + world_T_camera[:3, 3]
        np.testing.assert_allclose(back, three().points(), atol=1e-12)
        n = np.asarray(parsed.normals) @ world_T_camera[:3, :3].T
        np.testing.assert_allclose(n, np.tile(UP, (3, 1)), atol=1e-12)
    assert build_request(three(), Mode.POINTS)["frame"] == "world"
