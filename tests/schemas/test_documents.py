"""plan.json, messages and calibration datasets: valid examples pass, mistakes are named."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from planner.errors import DatasetError, InputError
from planner.io.validate import validate_file
from schemas.calibration import BeamDataset, CalibrationFile, HandEyeDataset
from schemas.messages import ErrorReply, JointState, JointTrajectory, TargetRequest
from schemas.plan import Plan
from schemas.yamlio import load_dataset, parse_message

Q = [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]


def plan_dict() -> dict[str, Any]:
    return {
        "schema": "beamrelay.plan/1",
        "scenario": {
            "system": {
                "laser": {"world_T_laser": {"xyz": [0, 0, 0]}},
                "robots": [
                    {"name": "arm0", "mirror": {"flange_T_mirror": {}, "size": [0.075, 0.075]}}
                ],
            },
            "targets": {"points": [[0.5, 0, 0]]},
        },
        "robots": ["arm0"],
        "joint_names": {"arm0": ["a", "b", "c", "d", "e", "f"]},
        "targets": [{"id": 0, "p": [0.5, 0, 0], "n": None}],
        "solutions": [
            {
                "target": 0,
                "status": "ok",
                "reason": None,
                "q": {"arm0": Q},
                "spot": [0.5, 0, 0],
                "error": 1e-12,
                "hits": [{"robot": "arm0", "p": [0, 0, 0.3], "uv": [0.001, 0.0]}],
                "solve_time": 0.0008,
                "iterations": 6,
            }
        ],
        "trajectory": {
            "t": [0.0, 0.002],
            "q": {"arm0": [Q, Q]},
            "qd": {"arm0": [[0.0] * 6] * 2},
            "qdd": {"arm0": [[0.0] * 6] * 2},
            "segments": [{"kind": "approach", "t0": 0.0, "t1": 0.002}],
        },
        "metrics": {"n_targets": 1, "n_ok": 1, "error_max": 0.0, "extra": {"ik_ms": 0.8}},
    }


def write(tmp_path: Path, name: str, data: object) -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def test_plan_valid_and_dumps_schema_key(tmp_path: Path) -> None:
    kind, plan = validate_file(write(tmp_path, "plan.json", plan_dict()))
    assert kind == "plan" and isinstance(plan, Plan)
    assert plan.model_dump(mode="json")["schema"] == "beamrelay.plan/1"
    assert Plan.model_validate(plan.model_dump(mode="json")) == plan


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d["solutions"][0].update(status="failed"), "solutions[0].reason: required"),
        (lambda d: d["solutions"][0].update(reason="bored"), "solutions[0].reason: expected"),
        (lambda d: d["solutions"][0]["q"].update(arm0=Q[:5]), "solutions[0].q.arm0: expected 6"),
        (lambda d: d["trajectory"]["q"]["arm0"].pop(), "trajectory.q.arm0: expected 2 rows"),
        (lambda d: d["metrics"].update(speed=1.0), "metrics.speed: unknown key"),
        (lambda d: d["metrics"]["extra"].update(x="a"), "metrics.extra.x: expected a number"),
        (lambda d: d["scenario"].pop("targets"), "scenario.targets: missing required key"),
        (lambda d: d.update(schema="beamrelay.plan/9"), "schema: unknown schema"),
    ],
)
def test_plan_errors(tmp_path: Path, edit: Any, message: str) -> None:
    data = plan_dict()
    edit(data)
    with pytest.raises(InputError) as info:
        validate_file(write(tmp_path, "plan.json", data))
    assert str(info.value).startswith(f"{tmp_path}/plan.json {message}")


def test_plan_without_trajectory() -> None:
    data = plan_dict()
    data["trajectory"] = None
    assert Plan.model_validate(data).trajectory is None


def test_request_message() -> None:
    body = {"schema": "beamrelay.request/1", "id": "r1", "points": [[0.1, 0, 0], [0.2, 0, 0]]}
    body |= {"normals": [[0, 0, 3], [0, 2, 0]], "mode": "path", "execute": False}
    req = parse_message(json.dumps(body), TargetRequest)
    assert req.normals == [[0, 0, 1], [0, 1, 0]] and req.frame == "world"
    with pytest.raises(InputError) as info:
        parse_message(json.dumps(body | {"points": [[0.1, 0, 0]]}), TargetRequest)
    assert info.value.where == "normals"
    with pytest.raises(InputError) as info:
        parse_message(json.dumps(body | {"execute": "yes"}), TargetRequest)
    assert (info.value.where, info.value.reason) == ("execute", "expected true or false, got 'yes'")
    with pytest.raises(InputError, match="invalid JSON"):
        parse_message(b"{nope", TargetRequest)
    with pytest.raises(InputError, match="expected at most 10000 items"):
        parse_message(
            json.dumps(body | {"points": [[0, 0, 0]] * 10001, "normals": None}), TargetRequest
        )
    with pytest.raises(InputError) as info:
        parse_message(json.dumps(body | {"points": [[0, 0, float("inf")]] * 2}), TargetRequest)
    assert info.value.where == "points[0][2]"


def test_joint_messages() -> None:
    names = ["a", "b"]
    JointState.model_validate({"t": 1.0, "names": names, "q": [0, 1], "qd": [0, 0]})
    with pytest.raises(ValidationError, match="expected 2 numbers"):
        JointState.model_validate({"t": 1.0, "names": names, "q": [0], "qd": [0, 0]})
    traj = {"schema": "beamrelay.trajectory/1", "robot": "arm0", "t": [0, 0.1], "names": names}
    traj |= {"q": [[0, 0], [0, 1]], "qd": [[0, 0], [0, 0]], "qdd": [[0, 0], [0, 0]]}
    JointTrajectory.model_validate(traj)
    with pytest.raises(ValidationError, match="times must increase"):
        JointTrajectory.model_validate(traj | {"t": [0, 0]})
    reply = ErrorReply(id="r1", error="bad", field="points[3]")
    assert reply.model_dump()["schema"] == "beamrelay.error/1"


def handeye() -> dict[str, Any]:
    board = [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]
    return {
        "schema": "beamrelay.handeye/1",
        "robot": "arm0",
        "mode": "eye_to_hand",
        "board": {"points": board},
        "samples": [{"q": Q, "points_camera": [[0, 0, 1], None, [0, 0.1, 1]]}],
    }


def beam() -> dict[str, Any]:
    return {
        "schema": "beamrelay.beam/1",
        "robot": "arm0",
        "samples": [
            {"q": {"arm0": Q}, "spot_world": [0.5, 0, 0], "board": 0},
            {"q": {"arm0": Q}, "spot_camera": [0, 0, 1], "board": 1},
        ],
    }


def test_datasets(tmp_path: Path) -> None:
    assert isinstance(load_dataset(write(tmp_path, "h.json", handeye())), HandEyeDataset)
    assert isinstance(load_dataset(write(tmp_path, "b.json", beam())), BeamDataset)
    bad = beam()
    bad["samples"][0]["spot_camera"] = [0, 0, 1]
    with pytest.raises(DatasetError, match=r"b.json samples\[0\]: give exactly one of"):
        load_dataset(write(tmp_path, "b.json", bad))
    bad = beam()
    bad["samples"][1]["q"] = {"arm1": Q}
    with pytest.raises(DatasetError, match=r"samples\[1\].q: has no joints for robot 'arm0'"):
        load_dataset(write(tmp_path, "b.json", bad))
    bad = handeye()
    bad["samples"][0]["points_camera"].pop()
    with pytest.raises(DatasetError, match=r"samples\[0\].points_camera: expected 3 entries"):
        load_dataset(write(tmp_path, "h.json", bad))
    bad = handeye() | {"extra": 1}
    with pytest.raises(DatasetError, match="extra: unknown key"):
        load_dataset(write(tmp_path, "h.json", bad))


def test_calibration_file(tmp_path: Path) -> None:
    path = tmp_path / "calibration.yaml"
    path.write_text(
        "system:\n  robots:\n    - name: arm0\n      mirror:\n"
        "        flange_T_mirror: {xyz: [0, 0, 0.031]}\n"
        "report: {residual_mean: 0.001}\n"
    )
    kind, model = validate_file(path)
    assert kind == "calibration" and isinstance(model, CalibrationFile)
    path.write_text(path.read_text().replace("mirror:", "miror:"))
    with pytest.raises(InputError, match=r"calibration.yaml:4 system.robots\[0\].miror: unknown"):
        validate_file(path)
