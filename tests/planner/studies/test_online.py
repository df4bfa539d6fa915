"""``study online``: the truth perturbation, the simulated measurement, a short trial."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.transforms import transform_points
from planner.studies import online


@pytest.fixture(scope="module")
def scn():
    return load_scenario(online.SCENARIO)


def test_truth_is_off_by_the_stated_amounts(scn) -> None:
    nominal = system_from_scenario(scn)
    truth = online.perturbed_truth(nominal, np.random.default_rng(0))
    d0, d1 = nominal.world_T_laser[:3, 2], truth.world_T_laser[:3, 2]
    assert np.rad2deg(np.arccos(d0 @ d1)) == pytest.approx(online.LASER_DEG, rel=1e-9)
    np.testing.assert_allclose(truth.world_T_laser[:3, 3], nominal.world_T_laser[:3, 3])
    M0, M1 = nominal.robots[0].mirror.flange_T_mirror, truth.robots[0].mirror.flange_T_mirror
    shift = M1[:3, 3] - M0[:3, 3]
    assert 1e3 * abs(shift @ M0[:3, 2]) == pytest.approx(online.MIRROR_MM, rel=1e-9)
    assert np.linalg.norm(np.cross(shift, M0[:3, 2])) < 1e-15  # along the normal only


def test_the_camera_measures_the_true_spot_with_d435_noise(scn) -> None:
    nominal = system_from_scenario(scn)
    truth = online.perturbed_truth(nominal, np.random.default_rng(1))
    world = online.World(scn, truth, seed=0)
    q = nominal.home
    _, centre, normal, _ = world.faces[0]
    true_spot = BeamModel(truth).trace(q, centre, normal).spot
    assert nominal.camera is not None
    got = [world.measure(q) for _ in range(50)]
    spots = transform_points(nominal.camera.world_T_camera, np.array(got))
    err = np.linalg.norm(spots - true_spot, axis=1)
    assert np.median(err) < 1e-3  # sub-millimetre spot noise at ~0.9 m
    assert np.std(spots, axis=0).max() > 1e-6  # but noisy
    # the nominal model predicts the spot millimetres away: that is what online refits remove
    assert np.linalg.norm(BeamModel(nominal).trace(q, centre, normal).spot - true_spot) > 2e-3


@pytest.mark.slow
def test_a_short_run_reduces_the_open_loop_error(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setattr(online, "CHECKPOINTS", (0, 12))
    monkeypatch.setattr(online, "N_EVAL", 4)
    figures = online.main(1, 0, tmp_path, 1, None)
    before, after = figures["checkpoints"]
    assert before["samples"] == 0 and after["samples"] == 12
    assert before["median_mm"] > 3.0  # 0.4 deg at the laser + 3 mm at the mirror
    assert after["median_mm"] < 0.3 * before["median_mm"]
    assert after["trials"] == 1 and after["gave_up"] == 0
    assert (tmp_path / "report.md").is_file() and (tmp_path / "online.png").is_file()


def test_the_two_surfaces_are_where_the_block_stands(scn) -> None:
    """The block stands on the board's +x half; targets on each face lie on that face (the
    sim camera's raycast finds them there) and never on the other object."""
    from planner.io.scenario import scene_objects
    from planner.model.scene import SceneModel

    items = list(scene_objects(scn))
    block = online.block_item(items)
    scene = SceneModel([*items, block])
    world_faces = online.faces([*items, block])
    assert [f[0] for f in world_faces] == ["board", "block"]
    board_top = items[0].world_T_object[2, 3] + items[0].extents[2] / 2
    assert block.world_T_object[2, 3] - block.extents[2] / 2 == pytest.approx(board_top)
    rng = np.random.default_rng(0)
    for name, centre, normal, half in world_faces:
        pts = centre + rng.uniform(-1, 1, (50, 2)) @ half.T
        hits = scene.cast(pts + 0.5 * normal, np.tile(-normal, (50, 1)))
        assert np.allclose(hits.t, 0.5, atol=1e-5)  # the face is the first surface from above
        assert {scene.names[i] for i in hits.object} == {name}
