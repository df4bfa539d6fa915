"""Visit order in linear memory: same tour quality as the dense all-pairs reference, memory
that grows linearly with the number of targets, every target exactly once."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from planner.model.system import DEFAULT_HOME, Limits
from planner.path.rest_to_rest import move_time
from planner.path.timing import points_trajectory
from planner.path.tour import candidate_lists, visit_order

HOME = np.array(DEFAULT_HOME)
LIM = Limits.ur_default()


def dense_reference(Q: np.ndarray, q_start: np.ndarray, lim: Limits) -> np.ndarray:
    """The former all-pairs algorithm: an (n+1)^2 cost matrix, nearest neighbour, then
    first-improvement 2-opt over every pair (open tour, fixed start)."""
    n = len(Q)
    P = np.vstack([q_start, Q])
    C = move_time(P[:, None, :], P[None, :, :], lim)
    tour, free = [0], np.ones(n + 1, dtype=bool)
    free[0] = False
    for _ in range(n):
        nxt = int(np.argmin(np.where(free, C[tour[-1]], np.inf)))
        tour.append(nxt)
        free[nxt] = False
    t = np.array(tour)
    for _ in range(50):
        improved = False
        for i in range(1, n):
            js = np.arange(i + 1, n + 1)
            after = np.where(js < n, t[np.minimum(js + 1, n)], -1)
            a = np.maximum(after, 0)
            gain = C[t[i - 1], t[i]] - C[t[i - 1], t[js]]
            gain += np.where(after >= 0, C[t[js], a] - C[t[i], a], 0)
            k = int(np.argmax(gain))
            if gain[k] > 1e-12:
                t[i : int(js[k]) + 1] = t[i : int(js[k]) + 1][::-1]
                improved = True
        if not improved:
            break
    return t[1:] - 1


def tour_time(Q: np.ndarray, order: np.ndarray) -> float:
    P = np.vstack([HOME, Q[order]])
    return float(move_time(P[:-1], P[1:], LIM).sum())


def grid_like(n_side: int, seed: int = 0) -> np.ndarray:
    """Configurations of a 3D target grid: a smooth, mildly nonlinear image of the grid in
    joint space (like the IK of a grid), shuffled."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(*[np.linspace(-1, 1, n_side)] * 3), -1).reshape(-1, 3)
    A = rng.normal(0, 0.25, (3, 6))
    Q = HOME + g @ A + 0.05 * np.sin(2 * g) @ rng.normal(0, 1, (3, 6))
    return Q[rng.permutation(len(Q))]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_same_quality_as_the_dense_reference(seed: int) -> None:
    Q = grid_like(7, seed)  # 343 targets
    new = visit_order(Q, HOME, LIM)
    assert sorted(new.tolist()) == list(range(len(Q)))
    ref = tour_time(Q, dense_reference(Q, HOME, LIM))
    given = tour_time(Q, np.arange(len(Q)))
    assert tour_time(Q, new) <= 1.02 * ref
    assert tour_time(Q, new) < 0.7 * given


def test_memory_grows_linearly() -> None:
    rng = np.random.default_rng(3)
    visit_order(HOME + rng.normal(0, 0.3, (50, 6)), HOME, LIM)  # imports, caches
    peaks = []
    for n in (2000, 4000):
        Q = HOME + rng.normal(0, 0.3, (n, 6))
        tracemalloc.start()
        visit_order(Q, HOME, LIM)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 2.6 * peaks[0]  # all pairs would quadruple
    # the all-pairs cost matrix alone would be 4001^2 x 6 x 8 B = 768 MB
    assert peaks[1] < 64e6


def test_candidates_are_the_cheapest_moves() -> None:
    Q = grid_like(5)
    P = np.vstack([HOME, Q])
    cand, cost = candidate_lists(P, LIM, k=6)
    C = move_time(P[:, None, :], P[None, :, :], LIM)
    np.fill_diagonal(C, np.inf)
    np.testing.assert_allclose(cost, np.take_along_axis(C, cand, axis=1), rtol=1e-12)
    assert np.all(np.diff(cost, axis=1) >= 0)
    # the scaled Chebyshev k-d tree finds the true nearest neighbour of nearly every row
    hits = np.mean(cand[:, 0] == np.argmin(C, axis=1))
    assert hits > 0.9


def test_duplicates_and_tiny_inputs() -> None:
    q = HOME + 0.1
    assert visit_order(np.empty((0, 6)), HOME, LIM).tolist() == []
    assert visit_order(q[None], HOME, LIM).tolist() == [0]
    order = visit_order(np.array([q, q, HOME + 0.2, q]), HOME, LIM)
    assert sorted(order.tolist()) == [0, 1, 2, 3]
    assert order[-1] == 2  # the three identical configurations first, then the far one


def test_given_order_is_the_file_order(system1) -> None:  # type: ignore[no-untyped-def]
    Q = grid_like(3)[:10]
    traj, rep = points_trajectory(system1, Q, order="given", rate=500.0)
    assert rep.order.tolist() == list(range(10))
    ends = [s for s in traj.segments if s.kind in ("approach", "move")]
    arrived = traj.q[[round(s.t1 * 500.0) for s in ends]]
    np.testing.assert_allclose(arrived, Q, atol=1e-12)
