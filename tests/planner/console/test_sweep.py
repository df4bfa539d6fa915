"""The marked path of an executed plan: spots placed on the trajectory by their joints,
compared with the planned path (known synthetic sweeps, brute-force distances)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from planner.console.sweep import COVER_GAP, covered_length, polyline_distance, sweep_of
from planner.io.plan import Plan
from planner.model.transforms import inv_T, look_at, transform_points
from tests.planner.service.plans import as_plan

SPEED = 0.1  # m/s of the synthetic spot along x
LASER_ON = [[0.2, 0.8]]
world_T_camera = look_at([-1.0, -1.0, 0.5], [0.05, 0.0, 0.0])


def plan(laser_on: list[list[float]] = LASER_ON) -> Plan:
    """A 1 s trajectory of one robot whose first joint is t (rad) and a 100 mm path along x."""
    t = np.linspace(0.0, 1.0, 501)
    q = np.zeros((len(t), 6))
    q[:, 0] = t
    q[:, 1] = -1.0
    targets = [{"id": k, "p": [0.01 * k, 0.0, 0.0]} for k in range(11)]
    return as_plan({"targets": targets, "trajectory": {"t": t.tolist(), "q": {"arm0": q.tolist()},
                                                       "laser_on": laser_on}})  # fmt: skip


def spots_at(times: np.ndarray, offset: float) -> list[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """Camera-frame spots at SPEED * t along x, ``offset`` m off the path in y, with joints."""
    world = np.column_stack([SPEED * times, np.full(len(times), offset), np.zeros(len(times))])
    cam = transform_points(inv_T(world_T_camera), world)
    return [(cam[i], {"arm0": np.array([t, -1.0, 0, 0, 0, 0])}) for i, t in enumerate(times)]


def test_spots_in_the_laser_on_interval_are_marked_with_their_distance_and_cover() -> None:
    times = np.arange(0.0, 1.0 + 1e-9, 0.04)  # 4 mm apart along the path
    sw = sweep_of(plan(), spots_at(times, 0.0005), world_T_camera)
    lit = (times >= 0.2) & (times <= 0.8)
    assert len(sw.marked) == int(lit.sum()) and sw.unlit == int((~lit).sum())
    assert sw.deviation_max == pytest.approx(0.0005, abs=1e-9)
    assert sw.deviation_median == pytest.approx(0.0005, abs=1e-9)
    np.testing.assert_allclose(sw.marked[:, 0], SPEED * times[lit], atol=1e-9)
    # from the first marked spot (x = 24 mm) to the last (80 mm)
    span = SPEED * (times[lit].max() - times[lit].min())
    assert sw.covered == pytest.approx(span, abs=1e-9)
    assert sw.length == pytest.approx(0.1)


def test_a_gap_in_the_marked_spots_is_not_covered() -> None:
    times = np.concatenate([np.linspace(0.2, 0.38, 10), np.linspace(0.6, 0.78, 10)])
    sw = sweep_of(plan(), spots_at(times, 0.0), world_T_camera)
    # two runs of 2 mm steps; the 20 mm jump between them is no cover
    assert sw.covered == pytest.approx(2 * 9 * 0.002, abs=1e-9)
    assert len(sw.marked) == len(times) and sw.unlit == 0


def test_no_laser_on_interval_marks_nothing_and_empty_inputs_are_no_sweep() -> None:
    times = np.arange(0.0, 1.0, 0.05)
    sw = sweep_of(plan(laser_on=[]), spots_at(times, 0.0), world_T_camera)
    assert len(sw.marked) == 0 and sw.unlit == len(times) and np.isnan(sw.deviation_max)
    sw = sweep_of(plan(), [], world_T_camera)
    assert len(sw.marked) == 0 and sw.unlit == 0 and sw.length == pytest.approx(0.1)
    no_traj = dataclasses.replace(plan(), trajectory=None)
    assert len(sweep_of(no_traj, spots_at(times, 0.0), world_T_camera).marked) == 0
    # spots recorded before any joint state of the robot cannot be placed
    blind = [(p, {}) for p, _ in spots_at(times, 0.0)]
    assert sweep_of(plan(), blind, world_T_camera).unlit == 0


def test_polyline_distance_matches_a_dense_sampling_of_the_polyline() -> None:
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.normal(size=(7, 3)), axis=0)
    pts = rng.normal(size=(40, 3)) * 2 + path.mean(axis=0)
    d, s = polyline_distance(path, pts)
    u = np.linspace(0, 1, 20001)[:, None]
    dense = np.vstack([a + u * (b - a) for a, b in itertools.pairwise(path)])
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.concatenate(
        [s0 + u[:, 0] * ln for s0, ln in zip(np.r_[0, np.cumsum(seg)][:-1], seg, strict=True)]
    )
    brute = np.linalg.norm(pts[:, None] - dense[None], axis=2)
    np.testing.assert_allclose(d, brute.min(axis=1), atol=1e-3)
    np.testing.assert_allclose(s, arc[brute.argmin(axis=1)], atol=2e-3)
    d1, s1 = polyline_distance(path[:1], pts)  # one point: the distance to it
    np.testing.assert_allclose(d1, np.linalg.norm(pts - path[0], axis=1))
    assert np.all(s1 == 0)


def test_covered_length_counts_only_steps_below_the_gap() -> None:
    s = np.array([0.0, 0.001, 0.003, 0.020, 0.021, 0.5])
    assert covered_length(s[::-1], COVER_GAP) == pytest.approx(0.001 + 0.002 + 0.001)
    assert covered_length(np.array([0.3]), COVER_GAP) == 0.0
