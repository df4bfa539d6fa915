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


def _rows(trial: int, taken: dict[int, int], errors: dict[int, list[float]]) -> list[dict]:
    return [{"trial": trial, "samples": n, "taken": taken[n], "target": j, "surface": "board",
             "version": 1, "error_mm": e, "refits": taken[n], "accepted": 1}
            for n, es in errors.items() for j, e in enumerate(es)]  # fmt: skip


def test_a_trial_that_gave_up_is_counted_apart(monkeypatch: pytest.MonkeyPatch) -> None:
    """Trial 2 gave up after 8 samples: it is in the rows of 0 and 5 samples and in none of
    the 20-sample row's figures, only in its gave_up count."""
    monkeypatch.setattr(online, "CHECKPOINTS", (0, 5, 20))
    full = {0: 0, 5: 5, 20: 20}
    rows = _rows(0, full, {0: [4.0, 6.0], 5: [2.0, 2.0], 20: [1.0, 3.0]})
    rows += _rows(1, full, {0: [8.0, 8.0], 5: [1.0, np.nan], 20: [2.0, 2.0]})
    rows += _rows(2, {0: 0, 5: 5, 20: 8}, {0: [9.0, 9.0], 5: [7.0, 7.0], 20: [50.0, 50.0]})
    by = {s["samples"]: s for s in online.summarise(rows)}
    assert [by[n]["gave_up"] for n in (0, 5, 20)] == [0, 0, 1]
    assert [by[n]["trials"] for n in (0, 5, 20)] == [3, 3, 2]
    # 20 samples: trials 0 and 1 only, per-trial means 2.0 and 2.0
    assert (by[20]["mean_mm"], by[20]["ci95_mm"], by[20]["max_mm"]) == (2.0, 0.0, 3.0)
    assert by[20]["median_mm"] == pytest.approx(2.0)
    # 5 samples: per-trial means 2, 1 (the unsolved target left out), 7; Student t over 3
    per = np.array([2.0, 1.0, 7.0])
    half = 4.302652729911275 * per.std(ddof=1) / np.sqrt(3)  # t_{0.975, 2}
    assert by[5]["mean_mm"] == pytest.approx(per.mean())
    assert by[5]["ci95_mm"] == pytest.approx(half)
    assert by[5]["unsolved"] == 1
