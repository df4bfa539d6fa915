"""Visit order of discrete targets in joint space, in memory linear in the target count.

The cost of going from one configuration to the next is the synchronised rest-to-rest move
time (s, :func:`planner.path.timing.move_time`: the slowest joint's jerk-limited time). It is
never tabulated for all pairs: a k-d tree over the joints scaled by the velocity limits
(Chebyshev distance = the cruise time of the slowest joint, a close proxy for the move
time) proposes the ``k`` nearest configurations of each one, and true move times are
evaluated for those candidate pairs only. The tour is an open path from a fixed start:

1. nearest neighbour: from the current configuration go to the unvisited candidate with
   the shortest true move time (the tree is rebuilt over the unvisited configurations when
   half of its points are used, so queries stay short);
2. 2-opt on the candidate lists (Johnson & McGeoch's neighbour-list 2-opt with don't-look
   bits): for each configuration a and each candidate c closer than a's successor b, the
   segment reversal that makes a-c and b-d edges is applied when it shortens the tour;

Memory is O(N k) (N configurations, k candidates each); time about O(N k log N) plus the
segment reversals. Joints in rad, times in s.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import numpy.typing as npt

from planner.model.system import Limits
from planner.model.transforms import Array
from planner.path.rest_to_rest import move_time

Order = npt.NDArray[np.intp]
K_NEIGHBOURS = 10  # candidates per configuration
EPS = 1e-12  # s: smallest gain worth a move


class _Costs:
    """True move times between rows of ``P`` (the start first), on demand, vectorised."""

    def __init__(self, P: Array, lim: Limits) -> None:
        self.P, self.lim, self._move_time = P, lim, move_time

    def pairs(self, i: npt.ArrayLike, j: npt.ArrayLike) -> Array:
        """Move times (s) between rows ``i`` and ``j`` (same shape; -1 = nowhere: cost 0)."""
        i, j = np.asarray(i), np.asarray(j)
        out = np.zeros(i.shape)
        ok = (i >= 0) & (j >= 0)
        if ok.any():
            out[ok] = self._move_time(self.P[i[ok]], self.P[j[ok]], self.lim)
        return out

    def one(self, i: int, j: int) -> float:
        if i < 0 or j < 0:
            return 0.0
        return float(self._move_time(self.P[i], self.P[j], self.lim))


def _scaled(P: Array, lim: Limits) -> Array:
    """Joints divided by the velocity limits (s at cruise): the k-d tree coordinates."""
    return np.asarray(P / lim.velocity, dtype=float)


def candidate_lists(P: Array, lim: Limits, k: int = K_NEIGHBOURS) -> tuple[Order, Array]:
    """For each row of ``P``: its ``k`` nearest other rows in the scaled Chebyshev metric,
    sorted by true move time, and those times (N x k each; rows padded with -1 / inf)."""
    from scipy.spatial import cKDTree

    n = len(P)
    kk = min(k + 1, n)
    _, idx = cKDTree(_scaled(P, lim)).query(_scaled(P, lim), k=kk, p=np.inf)
    idx = np.asarray(idx).reshape(n, kk)
    costs = _Costs(P, lim)
    cand = np.full((n, k), -1, dtype=np.intp)
    cost = np.full((n, k), np.inf)
    step = max(1, 50_000 // max(kk, 1))  # rows per block: bounded temporaries
    for r0 in range(0, n, step):
        rows = np.arange(r0, min(n, r0 + step))
        nb = idx[rows]
        c = costs.pairs(np.repeat(rows, kk).reshape(-1, kk), nb)
        c[nb == rows[:, None]] = np.inf  # not itself (duplicates stay as candidates)
        order = np.argsort(c, axis=1)[:, : min(k, kk - 1)]
        cand[rows, : order.shape[1]] = np.take_along_axis(nb, order, axis=1)
        cost[rows, : order.shape[1]] = np.take_along_axis(c, order, axis=1)
    cand[~np.isfinite(cost)] = -1
    return cand, cost


def nearest_neighbour_tour(P: Array, lim: Limits, k: int = K_NEIGHBOURS) -> Order:
    """Open tour over the rows of ``P`` starting at row 0: repeatedly the unvisited row with
    the shortest true move time among the ``k`` nearest unvisited in the scaled metric."""
    from scipy.spatial import cKDTree

    n = len(P)
    X = _scaled(P, lim)
    costs = _Costs(P, lim)
    free = np.ones(n, dtype=bool)
    free[0] = False
    tour = np.empty(n, dtype=np.intp)
    tour[0] = 0
    members = np.flatnonzero(free)
    tree, used = cKDTree(X[members]), 0
    cur = 0
    for step in range(1, n):
        if used * 2 > len(members):
            members = np.flatnonzero(free)
            tree, used = cKDTree(X[members]), 0
        kk = min(k, len(members))
        while True:
            _, hit = tree.query(X[cur], k=kk, p=np.inf)
            rows = members[np.atleast_1d(hit)]
            rows = rows[free[rows]]
            if len(rows) or kk >= len(members):
                break
            kk = min(2 * kk, len(members))
        c = costs.pairs(np.full(len(rows), cur), rows)
        cur = int(rows[int(np.argmin(c))])
        free[cur] = False
        used += 1
        tour[step] = cur
    return tour


class _Tour:
    """An open tour (``t[0]`` fixed) with positions and successor edge costs."""

    def __init__(self, t: Order, costs: _Costs) -> None:
        self.t, self.costs = t, costs
        self.n = len(t)
        self.pos = np.empty(self.n, dtype=np.intp)
        self.pos[t] = np.arange(self.n)
        self.edge = np.append(costs.pairs(t[:-1], t[1:]), 0.0)  # edge[i]: t[i] -> t[i+1]

    def at(self, i: int) -> int:
        return int(self.t[i]) if 0 <= i < self.n else -1

    def reverse(self, i: int, j: int) -> None:
        """Reverse positions i..j (1 <= i <= j); the edges at both ends are recomputed."""
        t = self.t
        t[i : j + 1] = t[i : j + 1][::-1].copy()
        self.pos[t[i : j + 1]] = np.arange(i, j + 1)
        if j > i:
            self.edge[i:j] = self.edge[i:j][::-1].copy()
        for e in (i - 1, j):
            self.edge[e] = self.costs.one(self.at(e), self.at(e + 1)) if e + 1 < self.n else 0.0

    def length(self) -> float:
        return float(self.edge[:-1].sum())


def two_opt(tour: _Tour, cand: Order, cand_cost: Array, max_moves: int | None = None) -> int:
    """Neighbour-list 2-opt with don't-look bits; returns the number of moves made."""
    n, moves = tour.n, 0
    queue = deque(int(x) for x in tour.t)
    queued = np.ones(n, dtype=bool)
    limit = max_moves if max_moves is not None else 50 * n
    while queue and moves < limit:
        a = queue.popleft()
        queued[a] = False
        i = int(tour.pos[a])
        for succ in (True, False):
            move = _best_move(tour, a, i, succ, cand[a], cand_cost[a])
            if move is None:
                continue
            lo, hi, touched = move
            tour.reverse(lo, hi)
            moves += 1
            for x in touched:
                if x >= 0 and not queued[x]:
                    queued[x] = True
                    queue.append(x)
            break
    return moves


def _best_move(tour: _Tour, a: int, i: int, succ: bool, cand: Order, cand_cost: Array
               ) -> tuple[int, int, tuple[int, ...]] | None:  # fmt: skip
    """The best improving 2-opt move that makes a-c an edge (c a candidate of a), breaking
    a's successor edge (``succ``) or predecessor edge; (reverse from, to, touched nodes)."""
    if succ:
        if i + 1 >= tour.n:
            return None
        b, ab = tour.at(i + 1), float(tour.edge[i])
    else:
        if i <= 1:  # the start stays first
            return None
        b, ab = tour.at(i - 1), float(tour.edge[i - 1])
    ok = (cand >= 0) & (cand_cost + EPS < ab)
    if not ok.any():
        return None
    cs, ac = cand[ok], cand_cost[ok]
    js = tour.pos[cs]
    if succ:
        ds = np.where(js + 1 < tour.n, tour.t[np.minimum(js + 1, tour.n - 1)], -1)
        cd = np.where(js + 1 < tour.n, tour.edge[js], 0.0)
    else:
        ds = np.where(js >= 1, tour.t[np.maximum(js - 1, 0)], -1)
        cd = np.where(js >= 1, tour.edge[np.maximum(js - 1, 0)], np.inf)
    bd = tour.costs.pairs(np.full(len(cs), b), ds)
    gain = ab + cd - ac - bd
    valid = (cs != b) & (ds != a)
    if not succ:
        valid &= js >= 1  # c's predecessor edge exists; the start never moves
    gain = np.where(valid, gain, -np.inf)
    m = int(np.argmax(gain))
    if not gain[m] > EPS:
        return None
    j, c, d = int(js[m]), int(cs[m]), int(ds[m])
    if succ:  # edges (a,b), (c,d) -> (a,c), (b,d)
        lo, hi = (i + 1, j) if j > i else (j + 1, i)
    else:  # edges (b,a), (d,c) -> (c,a), (d,b)
        lo, hi = (j, i - 1) if j < i else (i, j - 1)
    return lo, hi, (a, b, c, d)


def visit_order(Q: Array, q_start: Array, lim: Limits, k: int = K_NEIGHBOURS) -> Order:
    """Order of the rows of ``Q`` (n x nq, rad) that shortens the total move time from
    ``q_start``: nearest-neighbour tour on k-d tree candidates, then neighbour-list 2-opt
    and Or-opt (open tour, fixed start). Returns indices into ``Q``; memory O(n k)."""
    n = len(Q)
    if n <= 1:
        return np.arange(n)
    P = np.vstack([np.asarray(q_start, dtype=float), np.asarray(Q, dtype=float)])
    costs = _Costs(P, lim)
    cand, cand_cost = candidate_lists(P, lim, k)
    tour = _Tour(nearest_neighbour_tour(P, lim, k), costs)
    two_opt(tour, cand, cand_cost)
    return np.asarray(tour.t[1:] - 1, dtype=np.intp)
