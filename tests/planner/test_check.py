"""Independent checker: clean plans pass, violations detected (its numpy FK and trace are
tested in test_numpy_beam)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from planner.check import check_plan
from planner.errors import InputError
from planner.planning import plan_scenario
from tests.planner.test_planning import write_scenario


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
