"""``beamrelay check`` on the laser gate, as an outsider: a written plan with the laser on
during an approach, a run-out or a move, a mark that starts from rest, a missing or
malformed ``laser_on``, a tampered exposure."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from planner.io.plan_file import plan_json
from planner.model.settings import TrajectorySettings
from planner.plan.pipeline import PlanOutcome, run_scenario
from planner.plan.timed import time_solutions
from tests import cli_run

# The curve_path layout; an L of two 10 mm edges on the board (a 90 deg corner: two strokes).
L_PATH = """\
name: l-path
system:
  laser:
    world_T_laser: {xyz: [-0.491899, 0.188094, 0.074878], rpy_deg: [40, 0, 0]}
    power: 0.002
  robots:
    - name: arm0
      home: [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075], roi_margin: 0.005}
targets:
  path:
    points: [[-0.50, -0.57, -0.06], [-0.49, -0.57, -0.06], [-0.49, -0.56, -0.06]]
    normals: [[0, 0, 1], [0, 0, 1], [0, 0, 1]]
    spacing: 0.001
trajectory: {spot_speed: 0.02, rate: 500}
"""


@pytest.fixture(scope="module")
def outcome(tmp_path_factory: pytest.TempPathFactory) -> PlanOutcome:
    scn = tmp_path_factory.mktemp("l") / "l.yaml"
    scn.write_text(L_PATH)
    return run_scenario(scn, progress=False)


def beamrelay(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def _check(tmp_path: Path, doc: dict[str, Any]) -> subprocess.CompletedProcess[str]:
    f = tmp_path / "plan.json"
    f.write_text(plan_json(doc))
    return beamrelay("check", f)


def _text(out: subprocess.CompletedProcess[str]) -> str:
    return " ".join(out.stdout.split())


def _segment(doc: dict[str, Any], kind: str, n: int = 0) -> dict[str, float]:
    return [s for s in doc["trajectory"]["segments"] if s["kind"] == kind][n]


def test_the_plan_checks_clean(outcome: PlanOutcome, tmp_path: Path) -> None:
    doc = outcome.doc
    assert [s["kind"] for s in doc["trajectory"]["segments"]] == [
        "approach", "run_in", "path", "run_out", "move", "run_in", "path", "run_out"]  # fmt: skip
    assert len(doc["trajectory"]["laser_on"]) == 2
    out = _check(tmp_path, doc)
    assert out.returncode == 0, out.stdout


@pytest.mark.parametrize("kind", ["approach", "run_out", "move", "run_in"])
def test_laser_on_outside_the_marks_is_a_violation(outcome: PlanOutcome, tmp_path: Path,
                                                   kind: str) -> None:  # fmt: skip
    doc = copy.deepcopy(outcome.doc)
    seg = _segment(doc, kind)
    mid = round((seg["t0"] + seg["t1"]) / 2 * 500) / 500  # one sample inside the segment
    on = doc["trajectory"]["laser_on"]
    doc["trajectory"]["laser_on"] = sorted([*on, [mid, mid]])
    out = _check(tmp_path, doc)
    assert out.returncode == 1, out.stdout
    assert f"laser on during {kind} at t = {mid:.3f} s (1 sample(s))" in _text(out)


def test_laser_on_through_the_corner_is_caught(outcome: PlanOutcome, tmp_path: Path) -> None:
    # one interval over both strokes: on during the run-out, the move and the run-in, and
    # the spot leaves the path on the extensions
    doc = copy.deepcopy(outcome.doc)
    (a, _), (_, b) = doc["trajectory"]["laser_on"]
    doc["trajectory"]["laser_on"] = [[a, b]]
    text = _text(_check(tmp_path, doc))
    assert "laser on during run_out" in text
    assert "mm from the path" in text


def test_laser_off_on_a_mark_is_a_violation(outcome: PlanOutcome, tmp_path: Path) -> None:
    doc = copy.deepcopy(outcome.doc)
    doc["trajectory"]["laser_on"] = doc["trajectory"]["laser_on"][:1]
    doc["metrics"]["exposure"] = None
    out = _check(tmp_path, doc)
    assert out.returncode == 1
    second = _segment(doc, "path", 1)
    assert f"laser off during path at t = {second['t0']:.3f} s" in _text(out)


def test_a_mark_from_rest_is_a_violation(outcome: PlanOutcome, tmp_path: Path) -> None:
    o = outcome
    rest = time_solutions(o.system, o.targets, o.solutions,
                          TrajectorySettings.from_mapping(o.doc["scenario"]["trajectory"]),
                          path=o.path, skywriting=False)  # fmt: skip
    assert rest is not None
    doc = copy.deepcopy(o.doc)
    doc["trajectory"] = rest.trajectory.to_plan_dict(o.system)
    from planner.verify.marking import exposure

    doc["metrics"]["exposure"] = exposure(doc, 0.002)
    assert doc["metrics"]["exposure"]["fluence_max"] is None  # at rest: unbounded
    doc["metrics"]["duration"] = doc["trajectory"]["t"][-1]
    doc["metrics"]["extra"] = {}
    out = _check(tmp_path, doc)
    assert out.returncode == 1
    text = _text(out)
    assert "a mark starts at 0.0% of the speed" in text and "a mark ends at" in text
    # a reported slowdown over the ramps would excuse them: only where a limit binds, and
    # then the check accepts slower, never faster
    doc["trajectory"]["slowdowns"] = [
        {"s0": 0.0, "s1": 0.02, "t0": a, "t1": b, "limit": "acceleration", "robot": "arm0",
         "joint": 1, "speed": 0.0} for a, b in doc["trajectory"]["laser_on"]]  # fmt: skip
    excused = _check(tmp_path, doc)
    assert excused.returncode == 0, _text(excused)


def test_missing_and_malformed_laser_on(outcome: PlanOutcome, tmp_path: Path) -> None:
    doc = copy.deepcopy(outcome.doc)
    del doc["trajectory"]["laser_on"]
    out = _check(tmp_path, doc)
    assert out.returncode == 1 and "trajectory has no laser_on intervals" in _text(out)
    for bad in ([[2.0, 1.0]], [[1.0]], "on", [[0.0, 1.0], [0.5, 2.0]], [[0.0, float("nan")]]):
        doc["trajectory"]["laser_on"] = bad
        f = tmp_path / "bad.json"
        f.write_text(plan_json(doc))
        cli_run.assert_usage_error(cli_run.beamrelay("check", f), "laser_on")


def test_tampered_exposure_is_a_violation(outcome: PlanOutcome, tmp_path: Path) -> None:
    doc = copy.deepcopy(outcome.doc)
    ex = doc["metrics"]["exposure"]
    assert ex["fluence_min"] == pytest.approx(0.002 / 0.02, rel=0.02)
    ex["fluence_max"] *= 1.01
    out = _check(tmp_path, doc)
    assert out.returncode == 1 and "metrics.exposure.fluence_max" in _text(out)
