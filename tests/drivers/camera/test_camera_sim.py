"""Simulated camera against analytic geometry: board depth, noise model, the true spot."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest
from ruamel.yaml import YAML

from drivers.camera.sim import SPOT_WINDOW, SimCamera, depth_sigma, render_depth
from planner.io.scenario import scenario_from_dict, scene_objects, system_from_scenario
from planner.model.transforms import inv_T, rpy_to_matrix
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "paper_n1.yaml"
BOARD_TOP = -0.06  # m, top face of the paper_n1 board (centre -0.065, 10 mm thick)
BOARD_XY = (np.array([-0.642, -0.70]), np.array([-0.342, -0.40]))  # its top face's corners


def scenario(
    extra_scene: list[dict[str, Any]] | None = None, truth: dict[str, Any] | None = None
) -> Any:
    data = YAML(typ="safe").load(SCENARIO.read_text())
    data = copy.deepcopy(data)
    data["scene"] += extra_scene or []
    if truth is not None:
        data["truth"] = truth
    return scenario_from_dict(data, base_dir=SCENARIO.parent)


@pytest.fixture(scope="module")
def cam() -> SimCamera:
    scn = scenario()
    return SimCamera(system_from_scenario(scn, truth=True), scene_objects(scn), stride=2, seed=3)


def analytic_spot(system: Any, q: np.ndarray) -> np.ndarray:
    """Reflect the laser in the mirror plane (numpy only) and hit the board's top plane."""
    r = system.robots[0]
    M = r.world_T_base @ r.kinematics.fk(q) @ r.mirror.flange_T_mirror
    c, n = M[:3, 3], M[:3, 2]
    p0, v0 = system.world_T_laser[:3, 3], system.world_T_laser[:3, 2]
    h = p0 + (n @ (c - p0)) / (n @ v0) * v0
    v = v0 - 2 * (v0 @ n) * n
    return h + (BOARD_TOP - h[2]) / v[2] * v


def test_depth_matches_board_plane(cam: SimCamera) -> None:
    z, rays = render_depth(cam.scene, cam.camera, stride=2)
    R, c = cam.camera.world_T_camera[:3, :3], cam.camera.world_T_camera[:3, 3]
    d = rays @ R.T
    s = (BOARD_TOP - c[2]) / d[:, 2]  # ray parameter on the top plane = depth z
    hit = c + s[:, None] * d
    inside = np.all((hit[:, :2] > BOARD_XY[0] + 0.002) & (hit[:, :2] < BOARD_XY[1] - 0.002), axis=1)
    assert inside.sum() > 2000
    np.testing.assert_allclose(z[inside], s[inside], atol=1e-5)
    outside = np.all((hit[:, :2] < BOARD_XY[0] - 0.02) | (hit[:, :2] > BOARD_XY[1] + 0.02), axis=1)
    assert np.all(np.isinf(z[outside]))  # nothing else in the scene


def test_cloud_noise_follows_d435_model(cam: SimCamera) -> None:
    pts, meta = cam.points()
    assert pts.dtype == np.float32 and meta["width"] == 848 and meta["stride"] == 2
    assert len(pts) == len(cam._z)
    z_err = (pts[:, 2] - cam._z) / depth_sigma(cam._z, 430.0)
    assert abs(np.std(z_err) - 1.0) < 0.05 and abs(np.mean(z_err)) < 0.05
    # every point lies on its pixel's ray (noise is along the ray only)
    np.testing.assert_allclose(pts[:, :2] / pts[:, 2:], cam._rays[:, :2], atol=1e-5)
    w = pts.astype(float) @ cam.camera.world_T_camera[:3, :3].T + cam.camera.world_T_camera[:3, 3]
    top = np.abs(w[:, 2] - BOARD_TOP) < 0.02
    assert top.mean() > 0.9  # the board's top face fills most of the cloud


def test_true_spot_matches_analytic_reflection(cam: SimCamera) -> None:
    system = cam.system
    for dq in ([0, 0, 0, 0, 0, 0], [0.01, 0, 0, 0.02, -0.01, 0.3]):
        q = system.robots[0].home + np.array(dq)
        cam.on_joint_state("arm0", q)
        hit = cam.true_spot_world()
        assert hit is not None
        np.testing.assert_allclose(hit[0], analytic_spot(system, q), atol=1e-6)
        np.testing.assert_allclose(hit[2], [0, 0, 1], atol=1e-6)


def test_detected_spot_noise_and_confidence(cam: SimCamera) -> None:
    q = cam.system.robots[0].home
    cam.on_joint_state("arm0", q)
    truth = inv_T(cam.camera.world_T_camera) @ np.append(analytic_spot(cam.system, q), 1.0)
    det = [cam.spot() for _ in range(400)]
    p = np.array([d.p_camera for d in det if d is not None])
    assert len(p) == 400
    err = np.linalg.norm(p - truth[:3], axis=1)
    ray = truth[:3] / np.linalg.norm(truth[:3])
    along = (p - truth[:3]) @ ray
    sigma_z = depth_sigma(truth[2], 430.0) / SPOT_WINDOW  # plane fit over a 15 x 15 window
    assert np.std(along) == pytest.approx(sigma_z * np.linalg.norm(ray) / ray[2], rel=0.15)
    assert np.median(err) < 0.5e-3 and err.max() < 1.2e-3  # about the loop test's 1 mm
    # confidence = cos of the incidence on the board (beam 40 deg from vertical)
    assert det[0] is not None and det[0].confidence == pytest.approx(
        np.cos(np.radians(40)), abs=1e-4
    )


def test_no_spot_when_beam_leaves_mirror_or_no_joints() -> None:
    scn = scenario()
    cam = SimCamera(system_from_scenario(scn, truth=True), scene_objects(scn), stride=8)
    assert cam.spot() is None  # no joint state yet
    q = cam.system.robots[0].home + np.array([0, 0, 0, 0, 0.3, 0])  # tilt: beam off the ROI
    cam.on_joint_state("arm0", q)
    tr = cam.beam.trace(q)
    assert np.any(tr.roi < 0)
    assert cam.spot() is None


def test_obstacles_catch_or_hide_the_spot() -> None:
    home_spot = np.array([-0.4919028, -0.56786341, BOARD_TOP])
    mirror = np.array([-0.491899, -0.1333, 0.4579])
    mid = (home_spot + mirror) / 2
    ball = {"name": "ball", "sphere": 0.02, "world_T_object": {"xyz": mid.tolist()}}
    scn = scenario([ball])
    cam = SimCamera(system_from_scenario(scn, truth=True), scene_objects(scn), stride=8)
    cam.on_joint_state("arm0", cam.system.robots[0].home)
    hit = cam.true_spot_world()
    assert hit is not None
    assert np.linalg.norm(hit[0] - mid) == pytest.approx(0.02, abs=2e-4)  # on the ball's surface
    # a plate right in front of the camera hides everything
    c = cam.camera.world_T_camera
    plate = {
        "name": "plate",
        "box": [1.0, 1.0, 0.001],
        "world_T_object": {"matrix": (c @ np.diag([1.0, 1, 1, 1]) @ _tz(0.1)).tolist()},
    }
    scn2 = scenario([plate])
    cam2 = SimCamera(system_from_scenario(scn2, truth=True), scene_objects(scn2), stride=8)
    cam2.on_joint_state("arm0", cam2.system.robots[0].home)
    assert cam2.true_spot_world() is not None and cam2.spot() is None


def test_truth_geometry_moves_the_spot() -> None:
    """A laser tilted by 0.5 deg in ``truth`` moves the simulated spot (miscalibration)."""
    base = scenario()
    laser = base.model.system.laser.world_T_laser.matrix()
    tilted = laser.copy()
    tilted[:3, :3] = laser[:3, :3] @ rpy_to_matrix([np.radians(0.5), 0, 0])
    scn = scenario(truth={"system": {"laser": {"world_T_laser": {"matrix": tilted.tolist()}}}})
    true_sys = system_from_scenario(scn, truth=True)
    nominal = SimCamera(system_from_scenario(base, truth=True), scene_objects(base), stride=8)
    real = SimCamera(true_sys, scene_objects(scn), stride=8)
    q = true_sys.robots[0].home
    nominal.on_joint_state("arm0", q)
    real.on_joint_state("arm0", q)
    a, b = nominal.true_spot_world(), real.true_spot_world()
    assert a is not None and b is not None
    shift = np.linalg.norm(a[0] - b[0])
    np.testing.assert_allclose(b[0], analytic_spot(true_sys, q), atol=1e-6)
    assert 0.003 < shift < 0.02  # about 0.5 deg x ~1 m of beam: several millimetres


def _tz(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def test_spot_is_traced_once_per_joint_state_and_follows_new_joints() -> None:
    """The scene is static: the same joints give the same true spot (traced once), other
    joints another one, and a gated laser that is off gives none."""
    scn = scenario()
    cam = SimCamera(system_from_scenario(scn, truth=True), scene_objects(scn), stride=8, seed=1)
    q = cam.system.robots[0].home
    cam.on_joint_state("arm0", q)
    first = cam.true_spot_world()
    assert first is not None
    assert cam.true_spot_world() is first  # cached
    q2 = q + np.array([0.0, 0.0, 0.0, 0.0, 0.01, 0.0])
    cam.on_joint_state("arm0", q2)
    moved = cam.true_spot_world()
    assert moved is not None and np.linalg.norm(moved[0] - first[0]) > 1e-3
    assert np.allclose(moved[0], analytic_spot(cam.system, q2), atol=1e-6)
    cam.gated = True
    assert cam.true_spot_world() is None  # laser off


def test_a_frame_is_stamped_with_the_time_of_the_joint_states_it_shows() -> None:
    """The joint states reach the camera late; the frame shows the arm as they say, so it
    carries their stamp (a real camera's frame is stamped when the arm was there)."""
    from drivers.camera import sim

    scn = scenario()
    now = [1000.0]
    cam = SimCamera(system_from_scenario(scn, truth=True), scene_objects(scn), stride=8,
                    seed=3, clock=lambda: now[0])  # fmt: skip
    q = cam.system.robots[0].home
    cam.grab()
    assert cam.frame_time() == 1000.0  # no stamp: the clock
    cam.on_joint_state("arm0", q, 999.96)
    cam.grab()
    assert cam.frame_time() == 999.96  # 40 ms late states: the frame shows that moment
    now[0] = 999.96 + sim.STAMP_WINDOW + 0.1
    cam.grab()
    assert cam.frame_time() == now[0]  # a silent robot: the clock again
    cam.on_joint_state("arm0", q, now[0] + 1.0)  # a state from the future (clock skew)
    cam.grab()
    assert cam.frame_time() == now[0]


def test_the_spot_is_searched_near_the_predicted_spot_while_the_prediction_is_fresh() -> None:
    """A prediction 30 mm off (about 15 px at 0.87 m) still finds the spot, one 200 mm off
    (far outside the 60 px window, pinhole projection in numpy) does not, and once the
    prediction is older than its 1 s lifetime the whole image is searched again."""
    scn = scenario()
    now = [100.0]
    cam = SimCamera(system_from_scenario(scn, truth=True), scene_objects(scn), stride=4, seed=3,
                    clock=lambda: now[0])  # fmt: skip
    q = cam.system.robots[0].home
    cam.on_joint_state("arm0", q)
    cam.grab()
    truth = (inv_T(cam.camera.world_T_camera) @ np.append(analytic_spot(cam.system, q), 1.0))[:3]
    k = cam.camera.intrinsics

    def px(p: np.ndarray) -> np.ndarray:
        return np.array([k.fx * p[0] / p[2] + k.cx, k.fy * p[1] / p[2] + k.cy])

    near, far = truth + np.array([0.03, 0, 0]), truth + np.array([0.2, 0, 0])
    assert np.linalg.norm(px(near) - px(truth)) < 60 < np.linalg.norm(px(far) - px(truth))
    cam.on_predicted(near, now[0])
    assert cam.spot() is not None
    cam.on_predicted(far, now[0])
    assert cam.spot() is None and cam.outside_window == 1
    now[0] += 1.01  # the prediction is stale: the whole image again
    assert cam.spot() is not None
