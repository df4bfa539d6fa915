"""The node's pure side: request -> world targets (camera frame, path resampling) -> timing."""

from __future__ import annotations

import numpy as np
import pytest

from planner.bus.session import encode
from planner.errors import InputError
from planner.model.settings import TrajectorySettings
from planner.model.system import System, Targets
from planner.model.transforms import inv_T, transform_points
from planner.service.client import make_request
from planner.service.handler import PATH_SPACING, RequestHandler, make_plan_fn
from tests.planner.service.test_node import reachable_targets, system_with_camera


@pytest.fixture(scope="module")
def system() -> System:
    return system_with_camera()


def test_camera_frame_targets_use_world_T_camera(system: System) -> None:
    handler = RequestHandler(system, make_plan_fn(system, {}))
    p_world = reachable_targets(system, 3)
    camera_T_world = inv_T(system.camera.world_T_camera)  # type: ignore[union-attr]
    p_cam = transform_points(camera_T_world, p_world)
    n_world = np.array([[0, 0, 1.0], [0, 1.0, 0], [1.0, 0, 0]])
    n_cam = n_world @ camera_T_world[:3, :3].T
    req = handler.parse(encode(make_request(p_cam, frame="camera", normals=n_cam)))
    t = handler.targets(req)
    np.testing.assert_allclose(t.points, p_world, atol=1e-12)
    np.testing.assert_allclose(t.normals, n_world, atol=1e-12)


def test_path_requests_are_resampled_at_one_millimetre_with_sharp_corners(
    system: System,
) -> None:
    handler = RequestHandler(system, make_plan_fn(system, {}))
    corners = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.01, 0.0035, 0.0]])
    t = handler.targets(handler.parse(encode(make_request(corners, path=True))))
    assert t.kind == "path"
    steps = np.linalg.norm(np.diff(t.points, axis=0), axis=1)
    assert np.all(steps <= 1e-3 + 1e-12)  # at most 1 mm apart
    np.testing.assert_allclose(steps[:10], 1e-3, atol=1e-12)  # 10 mm edge: 1 mm chords
    np.testing.assert_allclose(steps[10:], 0.875e-3, atol=1e-12)  # 3.5 mm edge: 4 chords
    np.testing.assert_allclose(t.points[[0, -1]], corners[[0, -1]], atol=1e-12)
    assert len(t) == 15
    # the 90 deg turn (> the 20 deg corner angle) is marked sharp: two strokes sharing
    # the vertex sample, as a scenario path would be
    assert t.meta["sharp_corners"] == 1
    first, second = t.meta["strokes"]
    assert first[-1] == second[0] == 10
    np.testing.assert_allclose(t.points[10], corners[1], atol=1e-12)
    far = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]])  # 3000 samples > 2000
    with pytest.raises(InputError) as exc:
        handler.targets(handler.parse(encode(make_request(far, path=True))))
    assert exc.value.where == "points" and "2000" in exc.value.reason


def test_the_nodes_trajectory_starts_at_the_current_joints(system: System) -> None:
    """The node's plan function (the one pipeline, from the robots' joints): the trajectory
    starts where the robots are and visits the targets in the given order."""
    points = reachable_targets(system, 3, seed=7)
    targets = Targets(points)
    q_now = system.home + 0.03
    plan_fn = make_plan_fn(system, {}, settings=TrajectorySettings(dwell=0.2, rate=500.0))
    doc = plan_fn(targets, system.split_q(q_now), True).to_document()
    traj = doc["trajectory"]
    assert traj is not None
    assert [s["status"] for s in doc["solutions"]] == ["ok"] * 3
    sols = [np.asarray(s["q"]["arm0"]) for s in doc["solutions"]]
    q = np.asarray(traj["q"]["arm0"])
    t = np.asarray(traj["t"])
    np.testing.assert_allclose(q[0], q_now, atol=1e-12)
    np.testing.assert_allclose(np.diff(t), 1 / 500, atol=1e-12)
    kinds = [s["kind"] for s in traj["segments"]]
    assert kinds == ["approach", "dwell", "move", "dwell", "move", "dwell"]
    for seg, sol in zip(traj["segments"][1::2], sols, strict=True):  # dwells, in given order
        assert seg["t1"] - seg["t0"] == pytest.approx(0.2)
        i = round(seg["t0"] * 500)
        np.testing.assert_allclose(q[i], sol, atol=1e-9)


def test_a_path_request_with_a_corner_is_marked_in_two_strokes() -> None:
    """Through the node's own handler (scenario paper_n1): an L-shaped path request gives two
    laser-on intervals (the corner is marked sharp, with run-out and run-in), and the plan
    passes the independent checker."""
    from planner.service.handler import handler_from_scenario
    from planner.verify.check import check_plan
    from tests.paths import SCENARIOS

    handler = handler_from_scenario(SCENARIOS / "paper_n1.yaml")
    c = np.array([-0.49, -0.52, 0.0])
    pts = [c, c + np.array([0.02, 0, 0]), c + np.array([0.02, 0.015, 0])]
    req = handler.parse(encode(make_request(pts, path=True, normals=[[0, 0, 1]] * 3)))
    plan = handler.plan(req, None, trajectory=True).to_document()
    assert all(s["status"] == "ok" for s in plan["solutions"])
    laser_on = plan["trajectory"]["laser_on"]
    assert len(laser_on) == 2
    kinds = [s["kind"] for s in plan["trajectory"]["segments"]]
    assert kinds.count("run_in") == 2 and kinds.count("run_out") == 2
    findings = [f for r in check_plan(plan) for f in r.findings]
    assert findings == [], findings[:3]


def test_warm_up_plans_one_solved_target_down_the_beam_at_home(system: System) -> None:
    """The warm-up's target lies on the beam at home, so the plan it makes (and drops) is
    solved and its trajectory starts and stays at home: the IK, the path and the timing all
    ran. Then a path through it, across the beam, long enough for the coarse-to-fine warm
    start (4 coarse steps), every sample solved. A plan function that fails is no error."""
    from planner.beam.trace import trace_beam
    from planner.path.nlp import PathOptions

    plans: list[dict[str, object]] = []
    inner = make_plan_fn(system, {}, None, TrajectorySettings())

    def spy(targets: Targets, start: object, trajectory: bool) -> dict[str, object]:
        plan = inner(targets, start, trajectory)
        plans.append({"targets": targets, "trajectory": trajectory, "plan": plan.to_document()})
        return plan

    handler = RequestHandler(system, spy)
    assert handler.warm_up() > 0.0
    only, path = plans
    assert only["trajectory"] is True and path["trajectory"] is True
    point = only["targets"].points[0]  # type: ignore[attr-defined]
    beam = trace_beam(system, system.home, point)
    assert beam.error < 1e-9 and beam.target_ahead == pytest.approx(0.5, abs=1e-9)
    plan = only["plan"]
    assert plan["solutions"][0]["status"] == "ok"  # type: ignore[index]
    q = np.asarray(plan["trajectory"]["q"][system.robot_names[0]])  # type: ignore[index]
    np.testing.assert_allclose(q, np.tile(system.home, (len(q), 1)), atol=1e-4)
    samples = path["targets"]
    assert samples.kind == "path"  # type: ignore[attr-defined]
    ends = samples.points[[0, -1]] - point  # type: ignore[attr-defined]
    np.testing.assert_allclose(np.linalg.norm(ends, axis=1), 2 * PathOptions().coarse_spacing)
    np.testing.assert_allclose(ends @ beam.dirs[-1], 0.0, atol=1e-12)  # across the beam
    np.testing.assert_allclose(ends[0], -ends[1], atol=1e-12)  # centred on the target
    n_ok = path["plan"]["metrics"]["n_ok"]  # type: ignore[index]
    assert n_ok == len(samples.points) > 4 * PathOptions().coarse_spacing / PATH_SPACING

    def failing(*_: object) -> dict[str, object]:
        raise InputError("no", "points")

    assert RequestHandler(system, failing).warm_up() >= 0.0
