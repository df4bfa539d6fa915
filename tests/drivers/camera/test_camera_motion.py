"""The simulated camera sees a moving object where its motion puts it at the frame's time."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.sim import SimCamera
from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
from planner.model.transforms import inv_T
from tests.paths import SCENARIOS

SCENARIO = SCENARIOS / "breathing.yaml"
TOP = -0.06  # m, the phantom's top face at rest
AMPLITUDE = 0.005  # m, 0.25 Hz along +z


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(scope="module")
def world() -> tuple[SimCamera, Clock, np.ndarray]:
    scn = load_scenario(SCENARIO)
    clock = Clock()
    system = system_from_scenario(scn, truth=True)
    cam = SimCamera(system, scene_objects(scn), stride=2, seed=1, clock=clock)
    from planner.ik import BeamIK

    sol = BeamIK(system).solve(np.array([-0.492, -0.55, TOP]), np.array([0, 0, 1.0]))
    assert sol.ok and sol.q is not None
    return cam, clock, sol.q


def board_z_of_points(cam: SimCamera) -> np.ndarray:
    """World z of the noiseless depth pixels that land on the phantom's footprint."""
    z, rays = cam.depth()
    p_c = rays * z[:, None]
    T = cam.camera.world_T_camera
    p_w = p_c @ T[:3, :3].T + T[:3, 3]
    on = (np.abs(p_w[:, 0] + 0.492) < 0.09) & (np.abs(p_w[:, 1] + 0.55) < 0.09)
    return p_w[on, 2]


@pytest.mark.parametrize("t", [0.0, 1.0, 3.0, 0.5])
def test_depth_sees_the_top_face_where_the_sine_puts_it(world, t: float) -> None:
    cam, clock, _ = world
    clock.t = t
    cam.grab()
    z = board_z_of_points(cam)
    assert len(z) > 1000
    expected = TOP + AMPLITUDE * np.sin(2 * np.pi * 0.25 * t)
    np.testing.assert_allclose(z, expected, atol=2e-6)  # float32 raycast


def test_true_spot_lands_on_the_moved_surface(world) -> None:
    cam, clock, q = world
    cam.on_joint_state("arm0", q)
    clock.t = 0.0
    cam.grab()
    hit = cam.true_spot_world()
    assert hit is not None
    np.testing.assert_allclose(hit[0], [-0.492, -0.55, TOP], atol=1e-5)
    clock.t = 1.0  # board up 5 mm: the beam (fixed) stops 5 mm higher along its own ray
    cam.grab()
    spot, v, normal = cam.true_spot_world()  # type: ignore[misc]
    np.testing.assert_allclose(normal, [0, 0, 1], atol=1e-6)
    s = AMPLITUDE / -v[2]  # ray parameter back from the rest-pose spot to z = TOP + 5 mm
    np.testing.assert_allclose(spot, np.array([-0.492, -0.55, TOP]) - s * v, atol=1e-5)
    p_c = cam.spot()
    assert p_c is not None
    p_w = cam.camera.world_T_camera[:3, :3] @ p_c.p_camera + cam.camera.world_T_camera[:3, 3]
    assert np.linalg.norm(p_w - spot) < 3e-3  # the detection (noisy) sees the moved spot


def test_static_scenarios_keep_their_single_raycast() -> None:
    scn = load_scenario(SCENARIOS / "paper_n1.yaml")
    cam = SimCamera(system_from_scenario(scn, truth=True), scene_objects(scn), stride=4)
    z1, _ = cam.depth()
    z2, _ = cam.depth()
    assert z1 is z2  # no motion: the cached depth, no per-frame cast
    assert inv_T(cam.camera_T_world).shape == (4, 4)
