"""Simulated tracker: which targets it tracks, where it reports them, with what noise."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.tracker import SimTracker
from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
from planner.io.scenario import targets_from_scenario as targets_of
from planner.model.scene import SceneItem, tracked_objects
from planner.track.noise import MarkerNoise
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def setup() -> tuple[SimTracker, np.ndarray]:
    scn = load_scenario(SCENARIOS / "breathing.yaml")
    system = system_from_scenario(scn)
    t = targets_of(scn, system)
    objs = tracked_objects(scene_objects(scn), t.points, t.normals)
    assert system.camera is not None
    return SimTracker(objs, system.camera.world_T_camera, 430.0, seed=0), t.points


def test_targets_on_the_moving_phantom_are_tracked_under_its_name(setup) -> None:
    tracker, points = setup
    (obj,) = tracker.objects
    assert obj.item.name == "phantom"
    np.testing.assert_allclose(obj.points, points)
    assert obj.normals is not None


def test_targets_off_a_moving_object_are_not_tracked() -> None:
    from planner.model.motion import ObjectMotion

    box = SceneItem("b", "box", np.eye(4), extents=np.array([0.1, 0.1, 0.1]),
                    motion=ObjectMotion.sine([0, 0, 1], 0.005, 0.25))  # fmt: skip
    static = SceneItem("s", "box", np.eye(4), extents=np.array([0.1, 0.1, 0.1]))
    pts = np.array([[0.0, 0.0, 0.05], [0.0, 0.0, 0.0503], [0.0, 0.0, 0.0515], [0.3, 0, 0]])
    (obj,) = tracked_objects([box, static], pts, None)
    np.testing.assert_allclose(obj.points, pts[:2])  # on the surface (<= 1 mm), not beyond
    assert tracked_objects([static], pts, None) == []


def test_reports_move_with_the_object_and_carry_the_capture_time(setup) -> None:
    tracker, points = setup
    msgs = [tracker.measure(1.0)[0] for _ in range(400)]  # sine peak: +5 mm along z
    assert all(m.t == 1.0 and m.id == "phantom" and m.schema_ == "beamrelay.target_stream/1"
               for m in msgs)  # fmt: skip
    p = np.array([m.points[0] for m in msgs])
    truth = points[0] + [0.0, 0.0, 0.005]
    np.testing.assert_allclose(p.mean(axis=0), truth, atol=6e-5)
    cov = MarkerNoise(fx=430.0).covariance_world(truth, tracker.world_T_camera)
    np.testing.assert_allclose(np.cov(p.T), cov, atol=0.2 * np.abs(cov).max())
