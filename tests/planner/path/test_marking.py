"""Marking like a galvo scanner, on the shipped S-curve: the laser is off on every move
sample, sharp corners are marked sharp within the tolerance, the spot runs at the spot
speed over the whole of every mark (first and last millimetre included) and reaches it on
the run-in; the exposure follows. Spots are traced independently (numpy DH) onto the board
plane z = -0.06."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from planner.io.strokes import turn_angles
from planner.model.settings import TrajectorySettings
from planner.plan.pipeline import PlanOutcome, run_scenario
from planner.plan.timed import time_solutions
from planner.verify.check import check_plan
from planner.verify.marking import laser_mask
from planner.verify.spot import segment_mask
from planner.verify.trajectory import trace_last_ray
from schemas.plan import Plan
from tests.paths import SCENARIOS

BOARD_Z = -0.06
RATE, SPEED, TOL, POWER = 500.0, 0.02, 5e-5, 0.005


@pytest.fixture(scope="module")
def s_curve() -> PlanOutcome:
    return run_scenario(SCENARIOS / "s_curve.yaml", progress=False)


def _board_spots(doc: dict, idx: np.ndarray) -> np.ndarray:
    traj = doc["trajectory"]
    p, v = trace_last_ray(doc["scenario"], {r: np.asarray(q)[idx] for r, q in traj["q"].items()})
    return p + ((BOARD_Z - p[:, 2]) / v[:, 2])[:, None] * v


def _vertices(doc: dict) -> np.ndarray:
    return np.asarray(doc["scenario"]["targets"]["path"]["points"], dtype=float)


def _to_polyline(X: np.ndarray, V: np.ndarray) -> np.ndarray:
    a, ab = V[:-1], np.diff(V, axis=0)
    u = np.clip(np.einsum("mkj,kj->mk", X[:, None] - a, ab) / (ab * ab).sum(1), 0, 1)
    return np.linalg.norm(X[:, None] - (a + u[..., None] * ab), axis=2).min(axis=1)


def test_plan_is_valid_and_checks_clean(s_curve: PlanOutcome) -> None:
    doc = s_curve.doc
    Plan.model_validate(doc)
    assert not [f for r in check_plan(doc) for f in r.findings]
    assert doc["trajectory"]["slowdowns"] == []


def test_laser_off_on_every_move_sample(s_curve: PlanOutcome) -> None:
    traj = s_curve.doc["trajectory"]
    t = np.asarray(traj["t"])
    on = laser_mask(t, traj["laser_on"])
    marked = segment_mask(t, traj["segments"], "path")
    for kind in ("approach", "move", "run_in", "run_out"):
        dark = segment_mask(t, traj["segments"], kind) & ~marked  # boundary samples are shared
        assert dark.any() and not (on & dark).any(), kind
    assert on.sum() == marked.sum()
    # every laser interval is exactly one path segment
    paths = [(s["t0"], s["t1"]) for s in traj["segments"] if s["kind"] == "path"]
    assert [tuple(x) for x in traj["laser_on"]] == paths


def test_sharp_corners_are_marked_sharp_within_tolerance(s_curve: PlanOutcome) -> None:
    doc = s_curve.doc
    V = _vertices(doc)
    turns = np.degrees(turn_angles(V))
    sharp = V[1:-1][turns > 20.0]
    assert len(sharp) == 4  # the four 23.6 deg turns
    traj = doc["trajectory"]
    ends = []
    for t0, t1 in traj["laser_on"]:
        idx = np.arange(round(t0 * RATE), round(t1 * RATE) + 1)
        spots = _board_spots(doc, idx)
        assert _to_polyline(spots, V).max() <= TOL  # within the tolerance at every sample
        ends += [spots[0], spots[-1]]
    ends_arr = np.array(ends)
    # the laser switches within one servo step of the path's ends and of every sharp vertex
    step = SPEED / RATE
    points = [V[0], *sharp, V[-1]]
    for k, p in enumerate(points):
        near = np.linalg.norm(ends_arr - p, axis=1)
        assert (near < step + 1e-6).sum() == (1 if k in (0, len(points) - 1) else 2)
    # and never at a swept vertex
    swept = V[1:-1][turns <= 20.0]
    assert np.linalg.norm(ends_arr[:, None] - swept[None], axis=2).min() > 1e-3


def test_constant_speed_over_the_whole_mark(s_curve: PlanOutcome) -> None:
    doc = s_curve.doc
    traj = doc["trajectory"]
    for t0, t1 in traj["laser_on"]:
        idx = np.arange(round(t0 * RATE), round(t1 * RATE) + 1)
        spots = _board_spots(doc, idx)
        speed = np.linalg.norm(np.diff(spots, axis=0), axis=1) * RATE
        mm = round(0.001 / SPEED * RATE)  # steps in the first / last millimetre
        for part in (speed[:mm], speed[-mm:], speed):
            assert np.abs(part / SPEED - 1).max() < 0.02
    # the ramp happens on the run-in: from rest, along the first edge's extension (laser off)
    run_in = next(s for s in traj["segments"] if s["kind"] == "run_in")
    idx = np.arange(round(run_in["t0"] * RATE), round(run_in["t1"] * RATE) + 1)
    spots = _board_spots(doc, idx)
    V = _vertices(doc)
    u = (V[1] - V[0]) / np.linalg.norm(V[1] - V[0])
    off_line = np.linalg.norm(np.cross(spots - V[0], u), axis=1)
    along = (spots - V[0]) @ u
    assert off_line.max() < TOL and along.max() < 1e-4 and along.min() < -1e-3
    speed = np.linalg.norm(np.diff(spots, axis=0), axis=1) * RATE
    assert speed[0] < 0.05 * SPEED and speed[-1] > 0.98 * SPEED


def test_exposure_is_power_over_speed(s_curve: PlanOutcome) -> None:
    ex = s_curve.doc["metrics"]["exposure"]
    assert ex["dwell_energy"] is None
    assert POWER / SPEED / 1.02 < ex["fluence_min"] <= ex["fluence_max"] < POWER / SPEED / 0.98
    assert ex["fluence_max"] / ex["fluence_min"] < 1.04


def test_without_skywriting_the_mark_starts_from_rest(s_curve: PlanOutcome) -> None:
    o = s_curve
    settings = TrajectorySettings.from_mapping(o.doc["scenario"]["trajectory"])
    rest = time_solutions(o.system, o.targets, o.solutions, settings, path=o.path,
                          skywriting=False)  # fmt: skip
    assert rest is not None
    kinds = {s.kind for s in rest.trajectory.segments}
    assert "run_in" not in kinds and "run_out" not in kinds
    doc = dict(o.doc, trajectory=rest.trajectory.to_plan_dict(o.system))
    doc["metrics"] = dict(o.doc["metrics"], exposure=None)
    found = [f.message for r in check_plan(doc) if r.name == "laser" for f in r.findings]
    assert any("a mark starts at" in m for m in found), found


def test_the_gate_robot_gets_the_intervals_and_plays_them(s_curve: PlanOutcome) -> None:
    """plan -> JointTrajectory for the gate robot -> the driver's follower: the gate is on
    for exactly the planned intervals (in trajectory time, one period per switch)."""
    from drivers.robot.follower import TrajectoryFollower
    from drivers.robot.trajectory_check import check_message
    from planner.service.stream import trajectory_messages
    from schemas.messages import JointTrajectory

    doc = s_curve.doc
    body = trajectory_messages(s_curve.plan, "r1", "S")["arm0"]
    msg = JointTrajectory.model_validate_json(body)
    assert msg.laser_on == doc["trajectory"]["laser_on"]
    system = dict(doc["scenario"]["system"], laser={"world_T_laser": {}})
    plain = dataclasses.replace(s_curve.plan, scenario=dict(doc["scenario"], system=system))
    assert JointTrajectory.model_validate_json(trajectory_messages(plain)["arm0"]).laser_on is None
    ref = check_message(msg, "arm0", tuple(msg.names), s_curve.system.limits).reference
    f = TrajectoryFollower(ref.q[0], s_curve.system.limits, 1 / RATE)
    f.follow(ref)
    lit = []
    for _ in range(len(ref.t) + 50):
        f.step()
        lit.append(f.laser_edge() is not None)
    on_s = sum(lit) / RATE
    planned = sum(b - a for a, b in doc["trajectory"]["laser_on"])
    n = len(doc["trajectory"]["laser_on"])
    assert abs(on_s - planned) <= (n + 0.5) / RATE
