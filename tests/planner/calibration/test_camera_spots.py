"""Camera-frame data: the nominal-camera trap, eye-in-hand results that scenarios load, next steps.

Flow as a user runs it: ``calibrate simulate`` writes datasets from the scenario's ``truth``,
``calibrate handeye`` writes a calibration file, the scenario includes it, ``calibrate
beam`` uses camera-frame spots. Checked against the true geometry the data came from.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ruamel.yaml import YAML

from planner.beam.graph import BeamModel
from planner.cli import main
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.transforms import rotation_angle

from .cal_systems import TRUE_FLANGE_T_CAMERA, write_scenario


def _run(argv) -> int:
    try:
        main([str(a) for a in argv])
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


def _cli(*args) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "planner.cli", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=600,
    )


def _mirror_plane(path: Path) -> tuple[np.ndarray, float]:
    plane = YAML(typ="safe").load(path.read_text())["report"]["calibrated"]["mirror_plane"]
    return np.array(plane["normal"]), float(plane["offset_m"])


def _true_plane(scn: Path) -> tuple[np.ndarray, float]:
    M = system_from_scenario(load_scenario(scn), truth=True).robots[0].mirror.flange_T_mirror
    return M[:3, 2], float(M[:3, 2] @ M[:3, 3])


def _include(scn: Path, name: str, *files: str) -> Path:
    text = scn.read_text().replace("targets:", f"include: [{', '.join(files)}]\ntargets:", 1)
    out = scn.parent / name
    out.write_text(text)
    return out


@pytest.fixture(scope="module")
def fixed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scenario whose real camera is 3 cm / 2.7 deg off its nominal pose, and its datasets."""
    d = tmp_path_factory.mktemp("fixed")
    write_scenario(d / "scn.yaml", camera="fixed")
    common = ["--noise", "none", "--seed", "3"]
    assert _run(["calibrate", "simulate", d / "scn.yaml", "--kind", "beam", "--spots", "camera",
                 "--poses", "8", *common, "-o", d / "beam.json"]) == 0  # fmt: skip
    assert _run(["calibrate", "simulate", d / "scn.yaml", "--kind", "handeye", "--poses", "10",
                 *common, "-o", d / "he.json"]) == 0  # fmt: skip
    return d


def test_simulated_spots_are_in_the_true_camera_frame(fixed: Path) -> None:
    truth = system_from_scenario(load_scenario(fixed / "scn.yaml"), truth=True)
    doc = json.loads((fixed / "beam.json").read_text())
    assert all("spot_camera" in s and "spot_world" not in s for s in doc["samples"])
    cam = truth.world_T_camera()
    p_world = np.array([cam[:3, :3] @ s["spot_camera"] + cam[:3, 3] for s in doc["samples"]])
    q = np.array([s["q"]["arm0"] for s in doc["samples"]])
    for p, qk in zip(p_world, q, strict=True):  # each spot lies on the true reflected beam
        tr = BeamModel(truth).trace(qk)
        v = tr.dirs[-1]
        offset = p - tr.hits[-1]
        assert np.linalg.norm(offset - (offset @ v) * v) < 1e-9 and offset @ v > 0


def test_camera_spots_with_a_nominal_camera_warn_in_one_line(fixed: Path) -> None:
    proc = _cli("calibrate", "beam", fixed / "beam.json", "-s", fixed / "scn.yaml",
                "-o", fixed / "nominal.yaml")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith("warning: 24 spot_camera spots were mapped to the world with the")
    assert "nominal camera pose" in lines[0] and "include:" in lines[0]
    assert "calibrate handeye" in lines[0]
    # why it matters: the mirror plane comes out wrong by millimetres
    n, offset = _mirror_plane(fixed / "nominal.yaml")
    n_true, offset_true = _true_plane(fixed / "scn.yaml")
    assert abs(offset - offset_true) > 1e-3 or np.degrees(np.arccos(n @ n_true)) > 0.5


def test_camera_spots_calibrate_once_the_handeye_result_is_included(
    fixed: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(["calibrate", "handeye", fixed / "he.json", "-s", fixed / "scn.yaml",
                 "-o", fixed / "he.yaml"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert (
        "next: add `include: [he.yaml]` to " + str(fixed / "scn.yaml") + ", then collect beam data"
    ) in out
    scn2 = _include(fixed / "scn.yaml", "scn2.yaml", "he.yaml")
    assert (
        _run(["calibrate", "beam", fixed / "beam.json", "-s", scn2, "-o", fixed / "cal.yaml"]) == 0
    )
    captured = capsys.readouterr()
    assert "warning" not in captured.err
    assert "next: add `include: [cal.yaml]` to" in captured.out and "beamrelay plan" in captured.out
    n, offset = _mirror_plane(fixed / "cal.yaml")
    n_true, offset_true = _true_plane(fixed / "scn.yaml")
    assert np.linalg.norm(n - n_true) < 1e-6 and abs(offset - offset_true) < 1e-6
    report = YAML(typ="safe").load((fixed / "cal.yaml").read_text())["report"]
    assert report["camera_pose"] == {"from": str(fixed / "he.yaml"), "nominal": False}


@pytest.fixture(scope="module")
def flange(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scenario whose real camera rides on arm0's flange, and its eye-in-hand result."""
    d = tmp_path_factory.mktemp("flange")
    write_scenario(d / "scn.yaml", camera="flange")
    assert _run(["calibrate", "simulate", d / "scn.yaml", "--kind", "handeye", "--mode",
                 "eye_in_hand", "--poses", "10", "--noise", "none", "-o", d / "hei.json"]) == 0  # fmt: skip
    assert _run(["calibrate", "handeye", d / "hei.json", "-s", d / "scn.yaml",
                 "-o", d / "hei.yaml"]) == 0  # fmt: skip
    return d


def test_eye_in_hand_result_round_trips_through_include(flange: Path) -> None:
    doc = YAML(typ="safe").load((flange / "hei.yaml").read_text())
    assert doc["system"] == {
        "camera": {"robot": "arm0", "flange_T_camera": doc["system"]["camera"]["flange_T_camera"]}
    }
    scn = load_scenario(_include(flange / "scn.yaml", "scn2.yaml", "hei.yaml"))
    cam = system_from_scenario(scn).camera
    assert cam is not None and cam.robot == "arm0" and cam.flange_T_camera is not None
    # noise-free data: the calibration is exact to its solver tolerance
    assert np.linalg.norm(cam.flange_T_camera[:3, 3] - TRUE_FLANGE_T_CAMERA[:3, 3]) < 1e-7
    assert rotation_angle(cam.flange_T_camera[:3, :3].T @ TRUE_FLANGE_T_CAMERA[:3, :3]) < 1e-7
    assert not scn.camera_is_nominal


def test_eye_in_hand_camera_spots_use_the_joints_of_each_sample(flange: Path) -> None:
    """The camera moves with arm0: each spot_camera is mapped at that sample's arm0 joints."""
    scn2 = _include(flange / "scn.yaml", "scn2.yaml", "hei.yaml")
    assert _run(["calibrate", "simulate", flange / "scn.yaml", "--kind", "beam", "--spots",
                 "camera", "--poses", "8", "--noise", "none", "-o", flange / "beam.json"]) == 0  # fmt: skip
    assert (
        _run(["calibrate", "beam", flange / "beam.json", "-s", scn2, "-o", flange / "cal.yaml"])
        == 0
    )
    n, offset = _mirror_plane(flange / "cal.yaml")
    n_true, offset_true = _true_plane(flange / "scn.yaml")
    assert np.linalg.norm(n - n_true) < 1e-6 and abs(offset - offset_true) < 1e-6


def test_spots_from_a_camera_on_another_robot_need_its_joints(tmp_path: Path, capsys) -> None:
    write_scenario(tmp_path / "scn.yaml", truth=False)
    text = (tmp_path / "scn.yaml").read_text()
    mirror = next(line for line in text.splitlines() if "flange_T_mirror" in line)
    text = text.replace(
        mirror, mirror + "\n    - name: arm1\n      world_T_base: {xyz: [0, 0.9, 0]}\n" + mirror
    )
    cam = next(line for line in text.splitlines() if "world_T_camera" in line)
    text = text.replace(cam, "    robot: arm1\n    flange_T_camera: {xyz: [0, 0.06, 0.02]}")
    (tmp_path / "scn.yaml").write_text(text)
    q = [0.0, -1.5, 1.5, -1.5, -1.5, 0.0]
    doc = {"schema": "beamrelay.beam/1", "robot": "arm0",
           "samples": [{"q": {"arm0": q}, "spot_camera": [0.0, 0.0, 0.5]}] * 4}  # fmt: skip
    (tmp_path / "b.json").write_text(json.dumps(doc))
    assert _run(["calibrate", "beam", tmp_path / "b.json", "-s", tmp_path / "scn.yaml"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"error: {tmp_path / 'b.json'} samples[0].q: spot_camera with the camera on arm1's"
        " flange needs arm1's joints in q"
    )


@pytest.mark.parametrize(
    "sample, where, words",
    [
        ({"q": {"arm0": [0, -90, 90, -90, -90, 0]}, "spot_world": [0.4, 0.1, 0.0]},
         "samples[0].q.arm0[1]", "did you give degrees?"),
        ({"q": {"arm0": [0, -1.5, 1.5, -1.5, -1.5, 0]}, "spot_world": [450, 100, 0]},
         "samples[0].spot_world", "did you give millimetres?"),
        ({"q": {"arm0": [0, -1.5, 1.5, -1.5, -1.5, 0]}, "spot_camera": [0.1, 0.2, -0.6]},
         "samples[0].spot_camera", "not in front of the camera"),
    ],
)  # fmt: skip
def test_beam_dataset_unit_and_frame_mistakes(tmp_path: Path, capsys, sample, where, words) -> None:
    write_scenario(tmp_path / "scn.yaml")
    path = tmp_path / "b.json"
    path.write_text(json.dumps({"schema": "beamrelay.beam/1", "robot": "arm0",
                                "samples": [sample] * 4}))  # fmt: skip
    assert _run(["calibrate", "beam", path, "-s", tmp_path / "scn.yaml"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"error: {path} {where}: "), err
    assert words in err


@pytest.mark.parametrize(
    "edit, where, words",
    [
        (lambda d: d["samples"][0]["q"].__setitem__(2, 90.0), "samples[0].q[2]", "degrees?"),
        (lambda d: d["samples"][1]["points_camera"].__setitem__(0, [30.0, 20.0, 600.0]),
         "samples[1].points_camera[0]", "millimetres?"),
        (lambda d: d["samples"][1]["points_camera"].__setitem__(3, [0.1, 0.0, -0.5]),
         "samples[1].points_camera[3]", "not in front of the camera"),
        (lambda d: d["board"]["points"].__setitem__(0, [30.0, 0.0, 0.0]),
         "board.points[0]", "millimetres?"),
    ],
)  # fmt: skip
def test_handeye_dataset_unit_and_frame_mistakes(fixed: Path, capsys, edit, where, words) -> None:
    doc = json.loads((fixed / "he.json").read_text())
    edit(doc)
    path = fixed / "bad_he.json"
    path.write_text(json.dumps(doc))
    assert _run(["calibrate", "handeye", path, "-s", fixed / "scn.yaml"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"error: {path} {where}: "), err
    assert words in err


def test_simulate_prints_the_next_step_and_checks_spots(tmp_path: Path, capsys) -> None:
    write_scenario(tmp_path / "scn.yaml")
    assert _run(["calibrate", "simulate", tmp_path / "scn.yaml", "--kind", "beam", "--poses", "2",
                 "--boards", "2", "--noise", "none", "-o", tmp_path / "b.json"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert f"next: beamrelay calibrate beam {tmp_path / 'b.json'} -s {tmp_path / 'scn.yaml'}" in out
    assert _run(["calibrate", "simulate", tmp_path / "scn.yaml", "--spots", "pixels"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --spots 'pixels': expected world or camera"
