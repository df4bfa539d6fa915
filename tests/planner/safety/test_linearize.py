"""The clearance rows' distance gradients against finite differences of coal's distances,
for arm-arm, arm-scene and beam-arm / beam-keep-out pairs (separated and penetrating)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from planner.model.transforms import make_T
from planner.safety import box, sphere
from planner.safety.beam import beam_points
from planner.safety.linearize import Linearizer, cut_matrix, polyline_jacobians
from planner.safety.model import Safety
from tests.planner.safety.worlds import REACH, UPRIGHT, relay

H = 1e-6  # rad, finite-difference step


def _pair_distance(rules: Safety, key: tuple[str, int], q: np.ndarray, end: np.ndarray) -> float:
    world = rules.world
    world.update(q)
    if key[0] == "arm":
        pin.computeDistance(world.geom_model, world.geom_data, key[1])
        return float(world.geom_data.distanceResults[key[1]].min_distance)
    bp = rules.beam_pairs
    bp.place(beam_points(world, q, end))
    pin.computeDistance(bp.model, bp.data, key[1])
    return float(bp.data.distanceResults[key[1]].min_distance)


def _check_gradients(rules: Safety, q: np.ndarray, end: np.ndarray | None) -> list[str]:
    lin = Linearizer(rules, margin=0.3)
    P = None if end is None else beam_points(rules.world, q, end)
    rows = lin.rows(q, P)
    assert rows
    kinds = []
    for r in rows:
        e = end if end is not None else np.zeros(3)
        assert r.distance == pytest.approx(_pair_distance(rules, r.key, q, e), abs=1e-12)
        fd = np.array([(_pair_distance(rules, r.key, q + H * u, e)
                        - _pair_distance(rules, r.key, q - H * u, e)) / (2 * H)
                       for u in np.eye(len(q))])  # fmt: skip
        np.testing.assert_allclose(r.gradient, fd, atol=1e-5, err_msg=r.label)
        kinds.append(r.key[0] + (" penetrating" if r.distance < 0 else ""))
    return kinds


def test_arm_pair_gradients_match_finite_differences() -> None:
    system = relay(gap=1.05)
    post = box("post", [0.1, 0.1, 0.1], make_T(p=[0.5, 0.25, 0.55]))
    rules = Safety(system, scene=[post])
    q = np.r_[REACH + np.array([0.0, -0.1, 0.2, 0.2, 0.3, 0.0]),
              REACH + np.array([0.05, 0.05, -0.1, 0.1, 0.0, 0.5])]  # fmt: skip
    kinds = _check_gradients(rules, q, None)
    assert "arm penetrating" in kinds and "arm" in kinds


def test_beam_pair_gradients_match_finite_differences() -> None:
    system = relay(gap=1.05)
    q = np.r_[UPRIGHT + 0.1, UPRIGHT - 0.1]
    rules0 = Safety(system)
    P = beam_points(rules0.world, q, np.zeros(3))
    end = P[-2] + 0.8 * (np.array([0.5, 0.0, 0.5]) - P[-2])
    eye = sphere("eye", 0.05, make_T(p=(P[-2] + end) / 2 + [0.0, 0.0, 0.03]))
    rules = Safety(system, keep_out=[eye])
    kinds = _check_gradients(rules, q, end)
    assert "beam penetrating" in kinds


def test_hit_jacobians_match_finite_differences() -> None:
    system = relay()
    rules = Safety(system)
    q = np.r_[UPRIGHT + 0.1, UPRIGHT - 0.1]
    J = polyline_jacobians(rules, q)
    assert np.all(J[0] == 0) and np.all(J[-1] == 0)
    for j in range(len(q)):
        u = np.eye(len(q))[j]
        fd = (beam_points(rules.world, q + H * u, np.zeros(3))
              - beam_points(rules.world, q - H * u, np.zeros(3)))[1:-1] / (2 * H)  # fmt: skip
        np.testing.assert_allclose(J[1:-1, :, j], fd, atol=1e-6)


def test_cut_matrix_pads_with_inactive_rows() -> None:
    system = relay(gap=1.05)
    rules = Safety(system)
    q = np.r_[REACH, REACH]
    rows = Linearizer(rules).rows(q)
    A, lb = cut_matrix(rows, len(rows) + 3, system.nq)
    assert np.all(A[len(rows) :] == 0) and np.all(np.isneginf(lb[len(rows) :]))
    r = rows[0]
    # at q0 the row asks for the missing distance plus the buffer
    assert A[0] @ q - lb[0] == pytest.approx(r.distance - r.required - 5e-4, abs=1e-12)
