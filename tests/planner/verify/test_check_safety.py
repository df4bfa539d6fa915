"""``beamrelay check`` catches hand-edited plans that break each safety rule: arm-arm,
arm-scene, beam through an arm, beam into a keep-out volume, a target inside one, the beam
back into the laser; the unedited plans pass."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.io.plan_file import plan_json
from planner.model.kinematics import RobotKinematics, ur5e_urdf_path
from planner.model.mirror import Mirror
from planner.model.transforms import inv_T, look_at
from planner.plan.pipeline import run_scenario
from planner.verify.check import check_plan
from planner.verify.numpy_beam import pose_matrix, ur5e_dh_fk
from planner.verify.safety_setup import Setup
from planner.verify.safety_shapes import arm_shapes
from planner.verify.urdf import UrdfChain
from tests import cli_run
from tests.paths import REPO

Doc = dict[str, Any]


@pytest.fixture(scope="module")
def face() -> Doc:
    return json.loads(plan_json(run_scenario(REPO / "scenarios" / "face_keepout.yaml",
                                             progress=False).doc))  # fmt: skip


@pytest.fixture(scope="module")
def shared() -> Doc:
    return json.loads(plan_json(run_scenario(REPO / "scenarios" / "n2_shared.yaml",
                                             progress=False).doc))  # fmt: skip


def _findings(doc: Doc, name: str) -> list[Any]:
    return next(r for r in check_plan(doc) if r.name == name).findings


def _solved(doc: Doc) -> dict[str, Any]:
    return next(s for s in doc["solutions"] if s["status"] == "ok")


def _dwell_rows(doc: Doc, k: int) -> np.ndarray:
    """Trajectory rows of the k-th dwell segment."""
    traj = doc["trajectory"]
    seg = [s for s in traj["segments"] if s["kind"] == "dwell"][k]
    t = np.asarray(traj["t"])
    return np.flatnonzero((t >= seg["t0"] - 1e-9) & (t <= seg["t1"] + 1e-9))


def test_unedited_plans_pass(face: Doc, shared: Doc) -> None:
    for doc in (face, shared):
        assert not _findings(doc, "safety") and not _findings(doc, "trajectory safety")


def test_target_inside_keep_out(face: Doc) -> None:
    doc, sol = copy.deepcopy(face), _solved(face)
    p = doc["targets"][sol["target"]]["p"]
    doc["scenario"]["keep_out"].append({"name": "mole", "sphere": 0.004,
                                        "world_T_object": {"xyz": p}})  # fmt: skip
    found = [f for f in _findings(doc, "safety") if f.target == sol["target"]]
    assert found and found[0].reason == "keep_out" and "inside keep_out/mole" in found[0].message
    assert found[0].value == pytest.approx(-0.004, abs=1e-9)


def test_beam_into_keep_out(face: Doc) -> None:
    doc, sol = copy.deepcopy(face), _solved(face)
    hit, p = np.asarray(sol["hits"][0]["p"]), np.asarray(doc["targets"][sol["target"]]["p"])
    doc["scenario"]["keep_out"].append({"name": "lash", "sphere": 0.003,
                                        "world_T_object": {"xyz": ((hit + p) / 2).tolist()}})  # fmt: skip
    found = [f for f in _findings(doc, "safety") if f.target == sol["target"]]
    assert found and found[0].reason == "keep_out"
    assert "beam arm0->target enters keep_out/lash" in found[0].message
    traj = _findings(doc, "trajectory safety")  # the dwell on that target has the laser on
    assert any("keep_out/lash" in f.message for f in traj)


def test_beam_back_into_the_laser(face: Doc) -> None:
    doc = copy.deepcopy(face)
    scn = doc["scenario"]
    laser = pose_matrix(scn["system"]["laser"]["world_T_laser"])
    robot = scn["system"]["robots"][0]
    flange_T_mirror = pose_matrix(robot["mirror"]["flange_T_mirror"])
    rows = _dwell_rows(doc, 0)
    q = np.asarray(doc["trajectory"]["q"]["arm0"][rows[0]])
    c = (ur5e_dh_fk(q) @ flange_T_mirror)[:3, 3]
    v0 = laser[:3, 2]
    h = laser[:3, 3] + ((c - laser[:3, 3]) @ v0) * v0  # on the beam
    mirror = Mirror(flange_T_mirror).place(h, -v0, np.array([1.0, 0.0, 0.0]), 0.0, np.zeros(2))
    branches = np.array(RobotKinematics.ur5e().analytic_ik(mirror @ inv_T(flange_T_mirror)))
    retro = branches[np.argmin(np.abs(branches - q).sum(axis=1))]
    for i in rows:
        doc["trajectory"]["q"]["arm0"][i] = retro.tolist()
    found = _findings(doc, "trajectory safety")
    assert any(f.reason == "keep_out" and "laser aperture" in f.message for f in found)


def test_beam_through_an_arm(face: Doc) -> None:
    doc, sol = copy.deepcopy(face), _solved(face)
    robot = doc["scenario"]["system"]["robots"][0]
    q = np.asarray(sol["q"]["arm0"])
    shapes = arm_shapes(np.eye(4), q[None], pose_matrix(robot["mirror"]["flange_T_mirror"]),
                        np.asarray(robot["mirror"]["size"]))  # fmt: skip
    forearm = next(s for s in shapes if s.name == "forearm")
    mirror = np.asarray(sol["hits"][0]["p"])
    F = (forearm.A[0] + forearm.B[0]) / 2
    laser = mirror + 1.8 * (F - mirror)  # the forearm between the laser and the mirror
    doc["scenario"]["system"]["laser"]["world_T_laser"] = {
        "matrix": look_at(laser, mirror).tolist()
    }
    found = [f for f in _findings(doc, "safety") if f.target == sol["target"]]
    assert found and found[0].reason == "occluded" and "arm0/forearm" in found[0].message


def test_arm_against_the_scene(face: Doc) -> None:
    doc, sol = copy.deepcopy(face), _solved(face)
    robot = doc["scenario"]["system"]["robots"][0]
    q = np.asarray(sol["q"]["arm0"])
    shapes = arm_shapes(np.eye(4), q[None], pose_matrix(robot["mirror"]["flange_T_mirror"]),
                        np.asarray(robot["mirror"]["size"]))  # fmt: skip
    elbow = next(s for s in shapes if s.name == "upper_arm_elbow")
    centre = ((elbow.A[0] + elbow.B[0]) / 2 + [0.0, 0.0, 0.09]).tolist()  # 9 cm above its axis
    doc["scenario"]["scene"].append({"name": "lamp", "box": [0.05, 0.05, 0.05],
                                     "world_T_object": {"xyz": centre}})  # fmt: skip
    found = [f for f in _findings(doc, "safety") if f.target == sol["target"]]
    assert found and found[0].reason == "collision"
    assert "arm0/upper_arm_elbow - scene/lamp" in found[0].message
    assert any("scene/lamp" in f.message for f in _findings(doc, "trajectory safety"))


def test_arm_against_arm(shared: Doc) -> None:
    doc, sol = copy.deepcopy(shared), _solved(shared)
    reach = [np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0]  # arm1 stretched out toward arm0
    sol = next(s for s in doc["solutions"] if s["target"] == sol["target"])
    sol["q"]["arm1"] = reach
    found = [f for f in _findings(doc, "safety") if f.target == sol["target"]]
    assert found and found[0].reason == "collision" and "arm0/" in found[0].message
    assert "arm1/" in found[0].message
    for i in range(40, 60):
        doc["trajectory"]["q"]["arm1"][i] = reach
    traj = _findings(doc, "trajectory safety")
    assert any("arm_arm" in f.message and "at t = 0.080 s" in f.message for f in traj)


def test_the_safety_setup_is_built_once_per_check(face: Doc, monkeypatch: pytest.MonkeyPatch
                                                  ) -> None:  # fmt: skip
    """Both safety checks (targets and trajectory) read one setup: the scene and keep-out
    volumes are read once per plan, a URDF robot's URDF once per plan as well (the setup
    takes the context's reading)."""
    built: list[Setup] = []
    from_plan = Setup.from_plan

    def counted(plan: Doc, *args: Any) -> Setup:
        built.append(from_plan(plan, *args))
        return built[-1]

    monkeypatch.setattr(Setup, "from_plan", counted)
    results = {r.name: r for r in check_plan(face)}
    assert results["safety"].checked > 0 and results["trajectory safety"].checked > 0
    assert results["trajectory safety"].figures["laser_on_samples"] > 0  # the beam is checked
    assert len(built) == 1
    read: list[Path] = []
    init = UrdfChain.__init__

    def reading(self: UrdfChain, path: Path, **kwargs: str) -> None:
        read.append(path)
        init(self, path, **kwargs)

    monkeypatch.setattr(UrdfChain, "__init__", reading)
    doc = copy.deepcopy(face)
    doc["scenario"]["system"]["robots"][0]["urdf"] = str(ur5e_urdf_path())
    results = {r.name: r for r in check_plan(doc)}
    assert any("a URDF arm" in w for w in results["safety"].warnings)
    assert len(built) == 2 and read == [ur5e_urdf_path()]  # the arm's URDF is read once


def test_cli_check_exits_1_on_an_edited_plan(face: Doc, tmp_path: Path) -> None:
    doc, sol = copy.deepcopy(face), _solved(face)
    doc["scenario"]["keep_out"].append({"name": "mole", "sphere": 0.004,
                                        "world_T_object": {"xyz": doc["targets"][sol["target"]]["p"]}})  # fmt: skip
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(doc))
    out = cli_run.beamrelay("check", path)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "keep_out/mole" in out.stdout and "Traceback" not in out.stderr


def test_keep_out_summary_of_the_face(face: Doc) -> None:
    from planner.verify.safety_report import keep_out_summary

    rows = {r["volume"]: r for r in keep_out_summary(face)}
    P = np.array([t["p"] for t in face["targets"]])
    for v in face["scenario"]["keep_out"]:
        centre = np.asarray(v["world_T_object"]["matrix"])[:3, 3]
        inside = np.linalg.norm(P - centre, axis=1) < v["sphere"]
        row = rows[v["name"]]
        assert row["targets_inside"] == inside.sum() == row["failed_keep_out"] > 0
        assert 0.0 < row["beam_min_m"] < 0.05 and 0.0 < row["laser_on_min_m"] < 0.05
        assert row["laser_on_samples"] > 0


def test_shared_space_moves_are_detoured(shared: Doc) -> None:
    """Without the rules a move of the two-arm plan brings the arms closer than the 20 mm
    clearance (the checker says so); with them the plan re-times that move through a
    waypoint and checks clean."""
    plain = run_scenario(REPO / "scenarios" / "n2_shared.yaml", progress=False, safety=False)
    plain_doc = json.loads(plan_json(plain.doc))
    assert any("arm_arm" in f.message for f in _findings(plain_doc, "trajectory safety"))
    assert shared["metrics"]["extra"]["safety_detours"] >= 1
    assert shared["metrics"]["n_ok"] == 25 and not _findings(shared, "trajectory safety")


def _near_miss(face: Doc, gap: float = 0.0004, r: float = 0.003) -> tuple[Doc, dict[str, Any]]:
    """A copy of ``face`` with a keep-out sphere ``gap`` m beside a solved target's beam
    arm0->target (perpendicular to it at its middle), and that solution."""
    doc, sol = copy.deepcopy(face), _solved(face)
    hit, p = np.asarray(sol["hits"][0]["p"]), np.asarray(doc["targets"][sol["target"]]["p"])
    d = (p - hit) / np.linalg.norm(p - hit)
    u = np.cross(d, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    c = (hit + p) / 2 + (r + gap) * u
    doc["scenario"]["keep_out"].append({"name": "brow", "sphere": r,
                                        "world_T_object": {"xyz": c.tolist()}})  # fmt: skip
    # plain numpy: the solved beam (last mirror hit -> spot) passes `gap` from the sphere
    spot = np.asarray(sol["spot"])
    s = np.clip((c - hit) @ (spot - hit) / np.sum((spot - hit) ** 2), 0, 1)
    assert np.linalg.norm(c - (hit + s * (spot - hit))) - r == pytest.approx(gap, abs=1e-6)
    return doc, sol


def _brow(doc: Doc, name: str, target: int | None = None) -> list[Any]:
    return [f for f in _findings(doc, name) if "keep_out/brow" in f.message
            and (target is None or f.target == target)]  # fmt: skip


def test_a_beam_inside_the_inflated_keep_out_is_flagged(face: Doc) -> None:
    doc, sol = _near_miss(face)
    assert not _brow(doc, "safety") and not _brow(doc, "trajectory safety")  # margin 0
    wide = copy.deepcopy(doc)
    wide["scenario"]["system"]["laser"]["beam_radius"] = 0.0005
    found = _brow(wide, "safety", sol["target"])
    assert found and found[0].reason == "keep_out" and "inflated by 0.50 mm" in found[0].message
    assert found[0].value == pytest.approx(0.0004, abs=1e-6) and found[0].bound == 0.0005
    assert _brow(wide, "trajectory safety")  # the dwell on that target has the laser on
    unsure = copy.deepcopy(doc)  # the included calibration's spot uncertainty, echoed
    unsure["scenario"]["safety"]["spot_uncertainty"] = 0.0002
    found = _brow(unsure, "safety", sol["target"])
    assert found and found[0].bound == pytest.approx(0.0006)
    unsure["scenario"]["safety"]["spot_uncertainty"] = 0.0001  # margin 0.3 mm < 0.4 mm
    assert not _brow(unsure, "safety")


def test_cli_check_flags_a_plan_inside_the_inflated_keep_out(face: Doc, tmp_path: Path) -> None:
    doc, _ = _near_miss(face)
    doc["scenario"]["system"]["laser"]["beam_radius"] = 0.0005
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(doc))
    out = cli_run.beamrelay("check", path)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "keep_out/brow" in out.stdout and "Traceback" not in out.stderr
