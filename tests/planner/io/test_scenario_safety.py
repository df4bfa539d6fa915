"""``keep_out`` volumes and ``safety`` settings in scenario files: parsed, located errors,
resolved into plan.json's scenario, turned into the planner's safety rules; and on the
command line (one line on stderr, exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from planner.errors import ScenarioError
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import (
    keep_out_objects,
    load_scenario,
    scenario_from_dict,
    system_from_scenario,
)
from planner.safety.model import Safety
from schemas.scenario import Scenario
from tests import cli_run
from tests.planner.io.test_scenario import BASE, short, write

KEEP = """\
keep_out:
  - {name: eye, sphere: 0.016, world_T_object: {xyz: [0.5, 0.1, 0.05]}}
  - {name: slab, box: [0.1, 0.2, 0.01]}
  - {name: nose, mesh: meshes/cube.ply, scale: 0.001, world_T_object: {xyz: [1, 0, 0]}}
safety: {clearance: 0.02, return_cone_deg: 15}
"""


def _cube(tmp: Path) -> None:
    import open3d as o3d

    (tmp / "meshes").mkdir(exist_ok=True)
    mesh = o3d.geometry.TriangleMesh.create_box(20, 20, 20).translate([-10, -10, -10])
    o3d.io.write_triangle_mesh(str(tmp / "meshes" / "cube.ply"), mesh)


def test_keep_out_and_safety_are_read(tmp_path: Path) -> None:
    _cube(tmp_path)
    scn = load_scenario(write(tmp_path / "s.yaml", BASE + KEEP))
    items = keep_out_objects(scn)
    assert [(i.name, i.shape) for i in items] == [("eye", "sphere"), ("slab", "box"),
                                                  ("nose", "mesh")]  # fmt: skip
    assert items[0].radius == 0.016 and np.allclose(
        items[0].world_T_object[:3, 3], [0.5, 0.1, 0.05]
    )
    assert items[2].mesh_path == tmp_path / "meshes" / "cube.ply" and items[2].scale == 0.001
    rules = Safety.from_scenario(scn, system_from_scenario(scn))
    assert rules.settings.clearance == 0.02
    assert rules.settings.return_cone == pytest.approx(np.radians(15))
    # the mesh is a 20 mm cube (mm file, scale 0.001) centred at (1, 0, 0)
    assert rules.target(np.array([1.0, 0.0, 0.005])) is not None
    assert rules.target(np.array([1.0, 0.0, 0.012])) is None
    assert rules.target(np.array([0.5, 0.1, 0.05])).evidence["distance_m"] == pytest.approx(-0.016)  # type: ignore[union-attr]


def test_defaults_without_the_keys(tmp_path: Path) -> None:
    scn = load_scenario(write(tmp_path / "s.yaml", BASE))
    assert scn.model.keep_out == [] and scn.model.safety.clearance == 0.01
    resolved = resolved_scenario_dict(scn)
    assert resolved["keep_out"] == []
    assert resolved["safety"] == {"clearance": 0.01, "return_cone_deg": 10.0,
                                  "return_radius": 0.01, "spot_uncertainty": 0.0}  # fmt: skip


def test_resolved_round_trip(tmp_path: Path) -> None:
    _cube(tmp_path)
    scn = load_scenario(write(tmp_path / "s.yaml", BASE + KEEP))
    resolved = json.loads(json.dumps(resolved_scenario_dict(scn)))
    Scenario.model_validate(resolved)
    eye = resolved["keep_out"][0]
    assert eye["sphere"] == 0.016 and np.allclose(np.array(eye["world_T_object"]["matrix"])[:3, 3],
                                                  [0.5, 0.1, 0.05])  # fmt: skip
    assert resolved["keep_out"][2]["mesh"] == str(tmp_path / "meshes" / "cube.ply")
    assert resolved["safety"]["clearance"] == 0.02
    again = scenario_from_dict(resolved)
    assert resolved_scenario_dict(again) == resolved


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        ("{name: eye, sphere: 50, ", "keep_out[0].sphere: 50 m: did you give millimetres?"),
        ("{name: eye, cylinder: [0.1, 0.2], ", "keep_out[0].cylinder: unknown key"),
        ("{name: eye, sphere: 0.016, box: [1, 1, 1], ", "keep_out[0].box: give only one shape"),
        ("{name: eye, sphere: -0.01, ", "keep_out[0].sphere"),
        ("{name: slab, sphere: 0.016, ", "duplicate keep_out volume name 'slab'"),
    ],
)
def test_keep_out_errors_are_located(tmp_path: Path, edit: str, expected: str) -> None:
    _cube(tmp_path)
    text = BASE + KEEP.replace("{name: eye, sphere: 0.016, ", edit)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", text))
    msg = short(exc, tmp_path)
    assert msg.startswith("s.yaml:") and expected in msg, msg


@pytest.mark.parametrize(
    ("safety", "expected"),
    [
        ("{clearance: 10}", "safety.clearance: 10 m is above 0.5 m: did you give millimetres?"),
        ("{clearance: -0.01}", "safety.clearance"),
        ("{clearence: 0.01}", "safety.clearence: unknown key"),
        ("{return_cone_deg: 120}", "safety.return_cone_deg"),
        ("{clearance: .nan}", "safety.clearance"),
    ],
)
def test_safety_errors_are_located(tmp_path: Path, safety: str, expected: str) -> None:
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + f"safety: {safety}\n"))
    msg = short(exc, tmp_path)
    assert msg.startswith("s.yaml:") and expected in msg, msg


def test_missing_keep_out_mesh_names_the_key(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + KEEP))
    assert "keep_out[2].mesh: file not found" in short(exc, tmp_path)


def test_cli_validate_reports_a_bad_keep_out_in_one_line(tmp_path: Path) -> None:
    path = write(tmp_path / "s.yaml", BASE + "keep_out:\n  - {name: eye, sphere: 50}\n")
    cli_run.assert_usage_error(cli_run.beamrelay("validate", path), "keep_out[0].sphere")
