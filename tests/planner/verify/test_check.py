"""Independent checker: clean plans pass, violations detected (its numpy FK and trace are
tested in test_numpy_beam)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError
from planner.plan.pipeline import plan_scenario
from planner.verify.check import check_plan
from tests.planner.plan.test_pipeline import write_scenario


@pytest.fixture(scope="module")
def plan_doc(tmp_path_factory: pytest.TempPathFactory) -> dict:  # type: ignore[type-arg]
    doc, _, _ = plan_scenario(write_scenario(tmp_path_factory.mktemp("c")), progress=False)
    return doc


def _violations(doc: dict) -> dict[str, int]:  # type: ignore[type-arg]
    return {r.name: len(r.findings) for r in check_plan(doc, Path("."))}


def test_clean_plan_passes(plan_doc: dict) -> None:  # type: ignore[type-arg]
    results = check_plan(plan_doc)
    assert all(not r.findings for r in results)
    spot = next(r for r in results if r.name == "spot")
    assert spot.checked == 18
    assert spot.figures["error_max_m"] <= 1e-12
    limits = next(r for r in results if r.name == "trajectory limits")
    assert limits.checked == len(plan_doc["trajectory"]["t"]) > 18
    qd = np.abs(np.asarray(plan_doc["trajectory"]["qd"]["arm0"])).max(axis=0)
    # finite differences at the rate vs the analytic velocities Ruckig reported
    assert limits.figures["velocity_max_ratio"] == pytest.approx((qd / np.pi).max(), rel=0.02)
    arrivals = next(r for r in results if r.name == "trajectory spot")
    assert arrivals.figures["arrival_deviation_max_m"] <= 1e-9


def test_perturbed_joint_is_a_spot_violation(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    doc["solutions"][1]["q"]["arm0"][4] += 1e-4  # wrist 2 tilts the mirror: spot moves ~0.1 mm
    v = _violations(doc)
    assert v["spot"] >= 1
    assert v["joint limits"] == 0


def test_limits_and_roi_violations(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    pans = [s["q"]["arm0"][0] for s in doc["solutions"]]
    bound = float(np.median(pans))
    doc["scenario"]["system"]["robots"][0]["limits"]["upper"][0] = bound
    doc["scenario"]["system"]["robots"][0]["mirror"]["roi_margin"] = 0.0385  # ROI half -1 mm
    v = _violations(doc)
    assert v["joint limits"] == sum(1 for p in pans if p > bound + 1e-12) > 0
    assert v["mirrors"] == 18  # every hit is 1 mm outside an ROI of negative size
    assert v["spot"] == 0


def test_not_a_plan_is_input_error() -> None:
    with pytest.raises(InputError):
        check_plan({"scenario": {}})


def ramp_trajectory(doc: dict, speed: float, n: int = 50) -> dict:  # type: ignore[type-arg]
    """``doc`` with its trajectory replaced by joint 0 ramping at ``speed`` rad/s (no segments)."""
    rate = doc["scenario"]["trajectory"]["rate"]
    q0 = np.asarray(doc["solutions"][0]["q"]["arm0"])
    t = np.arange(n) / rate
    q = np.tile(q0, (n, 1))
    q[:, 0] += speed * t
    qd = np.zeros_like(q)
    qd[:, 0] = speed
    out = copy.deepcopy(doc)
    out["trajectory"] = {"t": t.tolist(), "q": {"arm0": q.tolist()}, "qd": {"arm0": qd.tolist()},
                         "qdd": {"arm0": np.zeros_like(q).tolist()}, "segments": []}  # fmt: skip
    return out


def test_trajectory_over_velocity_limit(plan_doc: dict) -> None:  # type: ignore[type-arg]
    results = {r.name: r for r in check_plan(ramp_trajectory(plan_doc, 1.5 * np.pi))}
    (f,) = results["trajectory limits"].findings
    assert "velocity" in f.message and f.target is None
    assert f.value == pytest.approx(1.5 * np.pi, rel=1e-9) and f.bound == pytest.approx(np.pi)
    assert results["trajectory limits"].figures["velocity_max_ratio"] == pytest.approx(1.5)
    ok = {r.name: r for r in check_plan(ramp_trajectory(plan_doc, 0.9 * np.pi))}
    assert not ok["trajectory limits"].findings


def test_wrong_arrival_is_a_violation(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    seg = next(s for s in doc["trajectory"]["segments"] if s["kind"] == "move")
    i = round(seg["t1"] * doc["scenario"]["trajectory"]["rate"])
    doc["trajectory"]["q"]["arm0"][i][4] += 1e-3  # wrist 2 tilts the mirror at an arrival
    spot = {r.name: r for r in check_plan(doc)}["trajectory spot"]
    arrival, missed = spot.findings  # the arrival is off, so that target is never reached
    assert arrival.message.startswith("arrival") and "never reached" in missed.message
    # a 1 mrad mirror tilt turns the beam 2 mrad: ~0.6 m away the spot moves ~1 mm
    assert 2e-4 < arrival.value < 5e-3


def test_deleted_trajectory_is_a_violation(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = {**plan_doc, "trajectory": None}
    results = {r.name: r for r in check_plan(doc)}
    assert results["trajectory limits"].checked == 0
    (missing,) = results["trajectory limits"].findings
    assert "no trajectory" in missing.message
    (duration,) = results["metrics"].findings  # the metrics still announce its duration
    assert duration.message.startswith("metrics.duration")
    doc.pop("trajectory")
    assert {r.name: len(r.findings) for r in check_plan(doc)}["trajectory limits"] == 1


def test_plan_that_requested_no_trajectory_passes(plan_doc: dict) -> None:  # type: ignore[type-arg]
    # a plan answering a request that did not execute: no trajectory, and it says so
    doc = {**plan_doc, "trajectory": None, "trajectory_requested": False}
    doc["metrics"] = {**plan_doc["metrics"], "duration": None, "extra": {}}
    results = {r.name: r for r in check_plan(doc)}
    assert results["trajectory limits"].warnings == ["plan has no trajectory"]
    assert not [f for r in results.values() for f in r.findings]


def _messages(doc: dict, name: str) -> list[str]:  # type: ignore[type-arg]
    return [f.message for r in check_plan(doc) if r.name == name for f in r.findings]


@pytest.mark.parametrize("key", ["qd", "qdd"])
def test_zeroed_derivatives_are_violations(plan_doc: dict, key: str) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    rows = np.asarray(doc["trajectory"][key]["arm0"])
    doc["trajectory"][key]["arm0"] = np.zeros_like(rows).tolist()
    (msg,) = _messages(doc, "trajectory limits")
    assert f"declared {key}" in msg and " is 0 " in msg
    # the figure: the largest |difference| of the positions (velocities) the zeros hide
    q = np.asarray(plan_doc["trajectory"]["q" if key == "qd" else "qd"]["arm0"])
    biggest = np.abs(np.gradient(q, 1 / 500.0, axis=0)).max()
    found = next(f for r in check_plan(doc) for f in r.findings)
    assert found.value == pytest.approx(biggest, rel=0.25)
    assert not _messages(doc, "trajectory spot")  # positions untouched: the spot is fine


def test_scaled_velocities_are_violations(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    doc["trajectory"]["qd"]["arm0"] = (0.9 * np.asarray(doc["trajectory"]["qd"]["arm0"])).tolist()
    assert len(_messages(doc, "trajectory limits")) == 1
    ok = next(r for r in check_plan(plan_doc) if r.name == "trajectory limits")
    assert ok.figures["velocity_declared_gap_max_ratio"] < 0.1  # the real plan: far inside


@pytest.mark.parametrize(
    ("key", "edit"),
    [("n_ok", lambda m: m["n_ok"] - 1), ("n_targets", lambda m: m["n_targets"] + 1),
     ("error_max", lambda m: 0.0), ("error_median", lambda m: m["error_median"] * 2),
     ("solve_time_median", lambda m: 1e-6), ("duration", lambda m: m["duration"] / 2)],
)  # fmt: skip
def test_edited_metrics_are_violations(plan_doc: dict, key: str, edit: object) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    doc["metrics"][key] = edit(doc["metrics"])  # type: ignore[operator]
    (msg,) = _messages(doc, "metrics")
    assert msg.startswith(f"metrics.{key} is ")
    # the recomputed figure is the independent one: from the solutions / trajectory
    errors = [s["error"] for s in plan_doc["solutions"]]
    expected = {"n_ok": 18, "n_targets": 18, "error_max": max(errors),
                "error_median": float(np.median(errors)),
                "solve_time_median": float(np.median([s["solve_time"] for s in plan_doc["solutions"]])),
                "duration": plan_doc["trajectory"]["t"][-1]}[key]  # fmt: skip
    assert msg.endswith(f"the plan gives {expected}")


def test_edited_extra_figures_are_violations(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    doc["metrics"]["extra"]["failed_unreachable"] = 2
    doc["metrics"]["extra"]["joint_speed_max_ratio"] = 0.5
    msgs = _messages(doc, "metrics")
    assert len(msgs) == 2
    assert any("failed_unreachable is 2, the plan gives None" in m for m in msgs)
    qd = np.abs(np.asarray(plan_doc["trajectory"]["qd"]["arm0"])).max(axis=0) / np.pi
    assert any(m.endswith(f"the plan gives {qd.max()}") for m in msgs)
    assert not _messages(plan_doc, "metrics")


def test_truncated_trajectory_misses_targets(plan_doc: dict) -> None:  # type: ignore[type-arg]
    doc = copy.deepcopy(plan_doc)
    traj = doc["trajectory"]
    seg = [s for s in traj["segments"] if s["kind"] in ("approach", "move")][9]
    n = round(seg["t1"] * 500) + 1  # keep the first ten moves only
    for key in ("q", "qd", "qdd"):
        traj[key]["arm0"] = traj[key]["arm0"][:n]
    traj["t"] = traj["t"][:n]
    traj["segments"] = [s for s in traj["segments"] if s["t1"] <= seg["t1"] + 1e-9]
    doc["metrics"]["duration"] = traj["t"][-1]
    (msg,) = _messages(doc, "trajectory spot")
    assert msg.startswith("8 solved target(s) never reached")
