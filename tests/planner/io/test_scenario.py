"""Scenario loading: includes, truth, defaults, targets, resolved dict, shipped scenarios."""

from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from planner.errors import ScenarioError
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import (
    grid_points,
    load_scenario,
    scenario_from_dict,
    scene_objects,
    system_from_scenario,
    targets_from_scenario,
)
from planner.model.kinematics import ur5e_urdf_path
from planner.model.polyline import resample_path
from planner.model.system import DEFAULT_HOME, Limits
from schemas.scenario import Scenario
from tests.paths import REPO

SCENARIOS = REPO / "scenarios"

BASE = """\
name: base
system:
  laser:
    world_T_laser: {xyz: [0.6, -0.4, 0.3], rpy_deg: [0, -90, 0]}
  robots:
    - name: arm0
      limits: {lower: [-1, -2, -3, -4, -5, -6]}
      mirror:
        flange_T_mirror: {xyz: [0, 0, 0.03], rpy: [0.1, 0, 0]}
        size: [0.075, 0.075]
    - name: arm1
      world_T_base: {xyz: [1.2, 0, 0], rpy_deg: [0, 0, 180]}
      mirror:
        flange_T_mirror: {xyz: [0, 0, 0.03]}
        size: [0.075, 0.075]
  camera:
    world_T_camera: {xyz: [1, 1, 1], quat: [0, 0, 0, 1]}
    intrinsics: {width: 848, height: 480, fx: 430.0, fy: 430.0, cx: 424.0, cy: 240.0}
targets:
  points: [[0.5, 0.1, 0.0], [0.5, 0.2, 0.0]]
"""

CALIB = """\
system:
  robots:
    - name: arm0
      limits: {velocity: [1, 1, 1, 1, 1, 1]}
      mirror:
        flange_T_mirror: {xyz: [0, 0, 0.031]}
  camera:
    world_T_camera: {xyz: [2, 2, 2]}
report: {residual_mean: 0.001}
"""


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def short(exc: pytest.ExceptionInfo[ScenarioError], root: Path) -> str:
    return str(exc.value).replace(str(root) + "/", "")


# --- shipped scenarios --------------------------------------------------------------------
def trace_home(name: str) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Follow the beam through every mirror at home; returns the last ray and incidences."""
    scn = load_scenario(SCENARIOS / name)
    system = system_from_scenario(scn)
    p, v = system.world_T_laser[:3, 3], system.world_T_laser[:3, 2]
    incidences = []
    for robot in system.robots:
        M = robot.world_T_base @ robot.kinematics.fk(robot.home) @ robot.mirror.flange_T_mirror
        c, n = M[:3, 3], M[:3, 2]
        t = n @ (c - p) / (n @ v)
        hit = p + t * v
        assert t > 0 and n @ v < 0
        assert np.linalg.norm(hit - c) < 1e-5  # aimed at the mirror centre
        incidences.append(float(np.degrees(np.arccos(-v @ n))))
        p, v = hit, v - 2 * (v @ n) * n
    return p, v, incidences


@pytest.mark.parametrize("name", ["paper_n1.yaml", "n2_relay.yaml", "curve_path.yaml"])
def test_shipped_scenarios_relay_at_home(name: str) -> None:
    p, v, incidences = trace_home(name)
    assert max(incidences) < 60
    scn = load_scenario(SCENARIOS / name)
    targets = targets_from_scenario(scn, system_from_scenario(scn))
    d = targets.points - p
    ahead = d @ v
    assert np.all(ahead > 0.3)
    centre = targets.points.mean(axis=0)
    miss = np.linalg.norm(np.cross(centre - p, v))  # reflected beam heads to the targets
    assert miss < 0.02
    camera = system_from_scenario(scn).camera
    assert camera is not None
    P = (targets.points - camera.world_T_camera[:3, 3]) @ camera.world_T_camera[:3, :3]
    u = camera.intrinsics.fx * P[:, 0] / P[:, 2] + camera.intrinsics.cx
    assert np.all(P[:, 2] > 0) and np.all((u > 0) & (u < camera.intrinsics.width))


def test_paper_n1_grid() -> None:
    scn = load_scenario(SCENARIOS / "paper_n1.yaml")
    targets = targets_from_scenario(scn, system_from_scenario(scn))
    assert len(targets) == 1000 and targets.kind == "grid" and targets.normals is None
    assert np.allclose(np.ptp(targets.points, axis=0), 0.1)


# --- includes -----------------------------------------------------------------------------
def test_include_merge_semantics(tmp_path: Path) -> None:
    write(tmp_path / "calib" / "c.yaml", CALIB)
    path = write(tmp_path / "s.yaml", BASE + "include: [calib/c.yaml]\n")
    scn = load_scenario(path)
    system = system_from_scenario(scn)
    arm0, arm1 = system.robots
    # a pose replaces whole: the included xyz-only pose drops the base's rpy
    assert np.allclose(arm0.mirror.flange_T_mirror, _t(0.031))
    # a mapping merges key by key; a list replaces whole
    assert np.allclose(arm0.limits.lower, [-1, -2, -3, -4, -5, -6])
    assert np.allclose(arm0.limits.velocity, 1.0)
    # robots matched by name: arm1 untouched
    assert np.allclose(arm1.mirror.flange_T_mirror, _t(0.03))
    assert system.camera is not None
    assert np.allclose(system.camera.world_T_camera[:3, 3], [2, 2, 2])
    assert system.camera.intrinsics.width == 848
    assert scn.includes == ("calib/c.yaml",)


def _t(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def test_includes_apply_in_order(tmp_path: Path) -> None:
    write(tmp_path / "a.yaml", CALIB)
    write(tmp_path / "b.yaml", CALIB.replace("0.031", "0.032"))
    scn = load_scenario(write(tmp_path / "s.yaml", BASE + "include: [a.yaml, b.yaml]\n"))
    assert np.isclose(system_from_scenario(scn).robots[0].mirror.flange_T_mirror[2, 3], 0.032)


def test_include_unknown_robot_names_include_line(tmp_path: Path) -> None:
    write(tmp_path / "c.yaml", CALIB.replace("name: arm0", "name: arm9"))
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + "include: [c.yaml]\n"))
    assert (
        short(exc, tmp_path)
        == "c.yaml:3 system.robots[0].name: no robot named 'arm9' (robots: arm0, arm1)"
    )


def test_include_errors_point_into_include(tmp_path: Path) -> None:
    write(tmp_path / "c.yaml", CALIB.replace("{xyz: [0, 0, 0.031]}", "{xyz: [0, 0.031]}"))
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + "include: [c.yaml]\n"))
    assert (
        short(exc, tmp_path)
        == "c.yaml:6 system.robots[0].mirror.flange_T_mirror.xyz: expected 3 numbers, got 2"
    )
    write(tmp_path / "c.yaml", CALIB.replace("report:", "reprot:"))
    with pytest.raises(ScenarioError) as exc:
        load_scenario(tmp_path / "s.yaml")
    assert short(exc, tmp_path).startswith("c.yaml:9 reprot: unknown key")
    # a merged value that is invalid only in the scenario's context points at the include
    write(tmp_path / "c.yaml", CALIB.replace("velocity: [1, 1, 1, 1, 1, 1]", "velocity: [1, 1]"))
    with pytest.raises(ScenarioError) as exc:
        load_scenario(tmp_path / "s.yaml")
    assert (
        short(exc, tmp_path)
        == "c.yaml:4 system.robots[0].limits.velocity: expected 6 numbers (one per joint), got 2"
    )


def test_missing_include(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + "include:\n  - nope.yaml\n"))
    assert short(exc, tmp_path) == "s.yaml:22 include[0]: include file not found: nope.yaml"


# --- truth --------------------------------------------------------------------------------
def test_truth_overlay(tmp_path: Path) -> None:
    truth = "truth:\n  system:\n    robots:\n      - name: arm1\n        mirror:\n"
    truth += "          flange_T_mirror: {xyz: [0, 0, 0.035]}\n"
    scn = load_scenario(write(tmp_path / "s.yaml", BASE + truth))
    nominal, real = system_from_scenario(scn), system_from_scenario(scn, truth=True)
    assert np.isclose(nominal.robots[1].mirror.flange_T_mirror[2, 3], 0.03)
    assert np.isclose(real.robots[1].mirror.flange_T_mirror[2, 3], 0.035)
    assert np.allclose(
        real.robots[0].mirror.flange_T_mirror, nominal.robots[0].mirror.flange_T_mirror
    )
    assert np.allclose(real.world_T_laser, nominal.world_T_laser)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + truth.replace("arm1", "arm7")))
    assert short(exc, tmp_path) == "s.yaml:24 truth.system.robots[0].name: no robot named 'arm7'"
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + truth + "          size: [0.01, 0.01]\n"))
    assert short(exc, tmp_path) == (
        "s.yaml:27 truth.system.robots[1].mirror.size: leaves no area inside roi_margin 0.005"
    )


# --- defaults, urdf, files ----------------------------------------------------------------
def test_defaults_and_shared_kinematics(tmp_path: Path) -> None:
    system = system_from_scenario(load_scenario(write(tmp_path / "s.yaml", BASE)))
    arm0, arm1 = system.robots
    assert np.allclose(arm1.home, DEFAULT_HOME)
    assert np.allclose(arm1.limits.upper, Limits.ur_default().upper)
    assert arm0.mirror.roi_margin == 0.005
    assert arm0.kinematics is arm1.kinematics
    assert np.allclose(arm1.world_T_base[:3, 0], [-1, 0, 0])


def test_urdf_robot_relative_path_and_lengths(tmp_path: Path) -> None:
    (tmp_path / "models").mkdir()
    shutil.copy(ur5e_urdf_path(), tmp_path / "models" / "arm.urdf")
    text = BASE.replace("    - name: arm1\n", "    - name: arm1\n      urdf: models/arm.urdf\n")
    scn = load_scenario(write(tmp_path / "s.yaml", text))
    system = system_from_scenario(scn)
    assert system.robots[1].kinematics.source == str(tmp_path / "models" / "arm.urdf")
    resolved = resolved_scenario_dict(scn)
    assert resolved["system"]["robots"][1]["urdf"] == str(tmp_path / "models" / "arm.urdf")
    text = text.replace("urdf: models/arm.urdf\n", "urdf: models/arm.urdf\n      home: [0, 0]\n")
    scn = load_scenario(write(tmp_path / "s.yaml", text))
    with pytest.raises(ScenarioError) as exc:
        system_from_scenario(scn)
    assert (
        short(exc, tmp_path)
        == "s.yaml:13 system.robots[1].home: expected 6 numbers (one per joint), got 2"
    )
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", text.replace("arm.urdf", "missing.urdf")))
    assert short(exc, tmp_path).startswith("s.yaml:12 system.robots[1].urdf: file not found")


def test_home_outside_limits(tmp_path: Path) -> None:
    text = BASE.replace("      limits:", "      home: [0, 0, 0, 0, -5.5, 0]\n      limits:")
    with pytest.raises(ScenarioError) as exc:
        system_from_scenario(load_scenario(write(tmp_path / "s.yaml", text)))
    assert (
        short(exc, tmp_path)
        == "s.yaml:7 system.robots[0].home[4]: -5.5 rad is outside the joint limits [-5, 6.28319]"
    )


def test_scene_objects(tmp_path: Path) -> None:
    write(tmp_path / "meshes" / "face.ply", "ply\n")
    scene = "scene:\n  - {name: board, box: [0.3, 0.2, 0.01], world_T_object: {xyz: [1, 0, 0]}}\n"
    scene += "  - {name: face, mesh: meshes/face.ply, scale: 0.001}\n"
    scene += "  - {name: ball, sphere: 0.05}\n  - {name: can, cylinder: [0.03, 0.1]}\n"
    scn = load_scenario(write(tmp_path / "s.yaml", BASE + scene))
    items = scene_objects(scn)
    assert [i.shape for i in items] == ["box", "mesh", "sphere", "cylinder"]
    assert items[1].mesh_path == tmp_path / "meshes" / "face.ply" and items[1].scale == 0.001
    assert np.allclose(items[0].world_T_object[:3, 3], [1, 0, 0])
    assert (items[3].radius, items[3].height) == (0.03, 0.1)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write(tmp_path / "s.yaml", BASE + scene.replace("face.ply", "nose.ply")))
    assert short(exc, tmp_path).startswith("s.yaml:23 scene[1].mesh: file not found")
    with pytest.raises(ScenarioError) as exc:
        load_scenario(
            write(
                tmp_path / "s.yaml",
                BASE + scene.replace("sphere: 0.05", "sphere: 0.05, box: [1, 1, 1]"),
            )
        )
    assert short(exc, tmp_path) == "s.yaml:24 scene[2].sphere: give only one shape of box, sphere"


# --- targets ------------------------------------------------------------------------------
def test_grid_count_and_bounds() -> None:
    P = grid_points([1, 2, 3], [0.1, 0.2, 0.0], [3, 5, 1])
    assert P.shape == (15, 3)
    assert np.allclose(P.min(axis=0), [0.95, 1.9, 3]) and np.allclose(P.max(axis=0), [1.05, 2.1, 3])
    assert len(np.unique(P[:, 1])) == 5
    assert np.allclose(grid_points([1, 2, 3], [1, 1, 1], [1, 1, 1]), [[1, 2, 3]])


def polyline(n: int = 30) -> np.ndarray:
    s = np.linspace(0, 0.15, n)
    return np.column_stack([s, 0.01 * np.sin(40 * s), np.zeros(n)])


@pytest.mark.parametrize("closed", [False, True])
def test_path_resampling_spacing(closed: bool) -> None:
    V = polyline()
    N = np.column_stack(
        [np.zeros(30), np.sin(np.linspace(0, 1, 30)), np.cos(np.linspace(0, 1, 30))]
    )
    P, Ns = resample_path(V.tolist(), spacing=0.001, normals=N.tolist(), closed=closed)
    steps = np.linalg.norm(np.diff(P, axis=0), axis=1)
    assert np.all(np.abs(steps[:-1] - 0.001) < 1e-9)
    assert 0 < steps[-1] <= 0.001 + 1e-9
    assert np.allclose(P[0], V[0]) and np.allclose(P[-1], V[0] if closed else V[-1])
    assert Ns is not None and np.allclose(np.linalg.norm(Ns, axis=1), 1)
    assert np.allclose(Ns[0], N[0]) and np.allclose(Ns[-1], N[0] if closed else N[-1])
    # every sample lies on the polyline (distance to the nearest segment ~ 0)
    W = np.vstack([V, V[:1]]) if closed else V
    assert all(_dist_to_polyline(p, W) < 1e-12 for p in P[::7])


def _dist_to_polyline(p: np.ndarray, V: np.ndarray) -> float:
    best = np.inf
    for a, b in itertools.pairwise(V):
        u = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        best = min(best, float(np.linalg.norm(a + u * (b - a) - p)))
    return best


def test_path_straight_line_exact_count() -> None:
    P, N = resample_path([[0, 0, 0], [0.01, 0, 0]], spacing=0.001)
    assert len(P) == 11 and N is None
    assert np.allclose(P[:, 0], np.linspace(0, 0.01, 11))


def test_path_errors() -> None:
    with pytest.raises(ValueError, match="zero length"):
        resample_path([[0, 0, 0], [0, 0, 0]], spacing=0.001)
    with pytest.raises(ValueError, match="opposite"):
        resample_path([[0, 0, 0], [1, 0, 0]], spacing=0.1, normals=[[0, 0, 1], [0, 0, -1]])


def test_curve_path_scenario() -> None:
    scn = load_scenario(SCENARIOS / "curve_path.yaml")
    targets = targets_from_scenario(scn, system_from_scenario(scn))
    assert targets.kind == "path" and targets.normals is not None
    steps = np.linalg.norm(np.diff(targets.points, axis=0), axis=1)
    # one stroke (every turn is below corner_deg), sampled at most 1 mm apart (finer: the
    # blend arcs of the turns need it); each arc's midpoint is a sample (the vertex's target),
    # so the spacing varies a little around the arcs
    assert targets.meta["strokes"] == (tuple(range(len(targets))),)
    assert steps.max() <= 0.001 + 1e-12 and steps.max() - steps.min() < 0.05 * steps.max()
    assert 0.14 < steps.sum() < 0.16
    assert np.allclose(targets.normals, [0, 0, 1])


def test_camera_frame_targets(tmp_path: Path) -> None:
    text = BASE.replace(
        "{xyz: [1, 1, 1], quat: [0, 0, 0, 1]}", "{xyz: [1, 1, 1], rpy_deg: [0, 0, 90]}"
    )
    text = text.replace(
        "targets:\n", "targets:\n  frame: camera\n  normals: [[1, 0, 0], [0, 0, 1]]\n"
    )
    text = text.replace("[[0.5, 0.1, 0.0], [0.5, 0.2, 0.0]]", "[[0.5, 0.1, 0.4], [0.5, 0.2, 0.4]]")
    scn = load_scenario(write(tmp_path / "s.yaml", text))
    targets = targets_from_scenario(scn, system_from_scenario(scn))
    assert np.allclose(targets.points[0], [1 - 0.1, 1 + 0.5, 1 + 0.4])
    assert targets.normals is not None and np.allclose(targets.normals[0], [0, 1, 0])


# --- resolved dict ------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["paper_n1.yaml", "n2_relay.yaml", "curve_path.yaml"])
def test_resolved_dict_round_trip(name: str) -> None:
    scn = load_scenario(SCENARIOS / name)
    resolved = resolved_scenario_dict(scn)
    json.dumps(resolved)
    Scenario.model_validate(resolved)
    again = scenario_from_dict(json.loads(json.dumps(resolved)))
    assert resolved_scenario_dict(again) == resolved
    a, b = system_from_scenario(scn), system_from_scenario(again)
    assert np.allclose(a.world_T_laser, b.world_T_laser)
    for ra, rb in zip(a.robots, b.robots, strict=True):
        assert np.allclose(ra.world_T_base, rb.world_T_base) and np.allclose(ra.home, rb.home)
    ta, tb = targets_from_scenario(scn, a), targets_from_scenario(again, b)
    assert np.allclose(ta.points, tb.points)


def test_resolved_dict_contents(tmp_path: Path) -> None:
    write(tmp_path / "c.yaml", CALIB)
    truth = "truth:\n  system:\n    laser: {world_T_laser: {xyz: [0.6, -0.4, 0.31]}}\n"
    scn = load_scenario(write(tmp_path / "s.yaml", BASE + "include: [c.yaml]\n" + truth))
    resolved = resolved_scenario_dict(scn)
    robot = resolved["system"]["robots"][1]
    assert set(robot["world_T_base"]) == {"matrix"} and robot["model"] == "ur5e"
    assert set(robot["limits"]) == {"lower", "upper", "velocity", "acceleration", "jerk"}
    assert robot["mirror"]["roi_margin"] == 0.005 and resolved["include"] == []
    assert resolved["solver"] == {"tolerance": 1e-9, "max_iter": 200, "max_incidence_deg": 80.0}
    assert resolved["truth"]["system"]["laser"]["world_T_laser"]["matrix"][2][3] == 0.31
    again = scenario_from_dict(resolved)
    assert np.isclose(system_from_scenario(again, truth=True).world_T_laser[2, 3], 0.31)
