"""Dataset files: JSON round trip, schema validation at the boundary, camera-frame spots."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.calibration.dataset import beam_json, handeye_json, load_beam, load_handeye, write_json
from planner.calibration.simulate import simulate_beam
from planner.errors import DatasetError
from planner.model.transforms import inv_T, transform_points

from .cal_systems import AIM, eye_to_hand_data, nominal_system


def test_handeye_round_trip_with_unseen_markers(tmp_path):
    system = nominal_system()
    data, _, _ = eye_to_hand_data(system, 4, np.random.default_rng(0))
    P = data.points_camera.copy()
    P[1, 3] = np.nan
    doc = handeye_json(type(data)(data.robot, data.mode, data.board_points, data.q, P))
    assert doc["samples"][1]["points_camera"][3] is None
    write_json(tmp_path / "he.json", doc)
    back = load_handeye(tmp_path / "he.json")
    assert np.array_equal(back.q, data.q) and back.mode == "eye_to_hand"
    assert np.isnan(back.points_camera[1, 3]).all()
    assert np.array_equal(np.nan_to_num(back.points_camera), np.nan_to_num(P))


def test_beam_round_trip_and_camera_frame_spots(tmp_path):
    system = nominal_system()
    data = simulate_beam(system, "arm0", 3, 2, aim_world=AIM, rng=np.random.default_rng(1))
    write_json(tmp_path / "b.json", beam_json(data, system))
    back = load_beam(tmp_path / "b.json", system)
    assert np.array_equal(back.q, data.q) and np.array_equal(back.spots_world, data.spots_world)
    assert back.boards.tolist() == data.boards.tolist()
    doc = beam_json(data, system)
    assert system.camera is not None
    c_T_w = inv_T(system.camera.world_T_camera)
    for s in doc["samples"]:
        s["spot_camera"] = transform_points(c_T_w, np.array(s.pop("spot_world"))).tolist()
    write_json(tmp_path / "c.json", doc)
    assert np.allclose(
        load_beam(tmp_path / "c.json", system).spots_world, data.spots_world, atol=1e-14
    )


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(schema="beamrelay.handeye/1"), "schema"),
        (lambda d: d["samples"][0].update(extra=1), "extra"),
        (lambda d: d.update(robot="arm7"), "no joints for robot 'arm7'"),
        (
            lambda d: (
                [d.update(robot="arm7")]
                + [s.update(q={"arm7": s["q"]["arm0"]}) for s in d["samples"]]
            ),
            "unknown robot",
        ),
        (lambda d: d["samples"][0]["q"].update(arm0=[0.0] * 5), "expected 6 joints"),
    ],
)
def test_bad_beam_files_name_the_problem(tmp_path, edit, message):
    system = nominal_system()
    data = simulate_beam(system, "arm0", 2, 1, aim_world=AIM, rng=np.random.default_rng(2))
    doc = beam_json(data, system)
    edit(doc)
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(DatasetError, match=message):
        load_beam(tmp_path / "bad.json", system)


def test_missing_and_broken_files():
    with pytest.raises(DatasetError, match="not found"):
        load_handeye("/nonexistent/he.json")
