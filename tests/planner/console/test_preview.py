"""The preview of a plan: beams, failures, the swept spot, joints along the trajectory.
Plans come from the planner's own request handler (no bus)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from planner.console.preview import beam_polyline, joints_at, preview_of
from planner.io.plan import Plan
from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
from planner.model.scene import SceneModel
from planner.service.client import make_request
from planner.service.handler import handler_from_scenario
from schemas.messages import TargetRequest
from tests.paths import SCENARIOS

BOARD_TOP = -0.06


@pytest.fixture(scope="module")
def world() -> tuple[Any, Any, Any]:
    path = SCENARIOS / "paper_n1.yaml"
    scn = load_scenario(path)
    return handler_from_scenario(path), system_from_scenario(scn), SceneModel(scene_objects(scn))


def plan_of(handler: Any, points: list[list[float]], path: bool = False,
            normals: list[list[float]] | None = None) -> Plan:  # fmt: skip
    req = TargetRequest.model_validate(make_request(points, path=path, normals=normals))
    return handler.plan(req, None, trajectory=True)


def test_beams_end_on_the_planned_spots_and_failures_keep_their_reason(world: Any) -> None:
    handler, system, scene = world
    # the third lies under the board: the board is in the way
    plan = plan_of(
        handler, [[-0.52, -0.56, BOARD_TOP], [-0.47, -0.53, BOARD_TOP], [-0.49, -0.55, -0.2]]
    )
    pv = preview_of(plan, system, scene)
    assert (pv.n_ok, pv.n) == (2, 3)
    assert [f.target for f in pv.failed] == [2]
    assert pv.failed[0].reason == "occluded"
    assert np.allclose(pv.failed[0].p, [-0.49, -0.55, -0.2])
    for beam, sol in zip(pv.beams, plan.solutions[:2], strict=True):
        assert np.allclose(beam[0], system.world_T_laser[:3, 3])
        assert np.allclose(beam[-1], sol.spot)
        # the beam at the solution's joints, traced by the console and raycast onto the board
        # (open3d works in float32: ~1e-6 m over a metre), lands on the same spot
        q = dict(sol.q)
        assert np.linalg.norm(beam_polyline(system, q, scene)[-1] - sol.spot) < 1e-5
    assert plan.trajectory is not None
    assert pv.duration == pytest.approx(plan.trajectory.t[-1])


def test_the_swept_path_lies_on_the_board_along_the_requested_line(world: Any) -> None:
    handler, system, scene = world
    a, b = np.array([-0.52, -0.56, BOARD_TOP]), np.array([-0.47, -0.55, BOARD_TOP])
    plan = plan_of(handler, [a.tolist(), b.tolist()], path=True)
    pv = preview_of(plan, system, scene)
    assert len(pv.sweep) > 20
    assert np.allclose(pv.sweep[:, 2], BOARD_TOP, atol=1e-5)  # raycast onto the board's top
    d = (b - a) / np.linalg.norm(b - a)
    rel = pv.sweep - a
    off = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
    assert off.max() < 1e-4  # laser on: within the path tolerance (5e-5 m) plus the raycast


def test_joints_at_interpolates_the_trajectory(world: Any) -> None:
    handler, _, _ = world
    traj = plan_of(handler, [[-0.52, -0.56, BOARD_TOP]]).trajectory
    assert traj is not None
    T, Q = traj.t, traj.q["arm0"]
    k = len(T) // 2
    assert np.allclose(joints_at(traj, ("arm0",), T[k])["arm0"], Q[k])
    mid = 0.5 * (T[k] + T[k + 1])
    assert np.allclose(joints_at(traj, ("arm0",), mid)["arm0"], 0.5 * (Q[k] + Q[k + 1]))
    assert np.allclose(joints_at(traj, ("arm0",), -5.0)["arm0"], Q[0])
    assert np.allclose(joints_at(traj, ("arm0",), 1e9)["arm0"], Q[-1])


def test_a_beam_that_misses_the_mirror_stops_there(world: Any) -> None:
    _, system, scene = world
    q = {"arm0": np.array([1.5, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])}  # mirror swung away
    line = beam_polyline(system, q, scene)
    assert len(line) == 2
    v = system.world_T_laser[:3, 2]
    assert np.allclose(line[1] - line[0], v)  # 1 m along the laser's own axis
