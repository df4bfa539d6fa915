"""Warm start of the path NLP: a per-sample seed and continuation chain.

A single sample is seeded by the caller's :class:`Seeder` (the planning pipeline passes the
IK's closed-form family search; without one, a multi-start one-sample NLP); the chain then
walks along the path with
equality-constrained Newton steps (spot on the sample, a centring pull), extrapolating the
previous two samples. Where no valid configuration is found the sample gets a failure reason
with evidence, and the chain re-seeds further on and extends backward into the gap.

Batched helpers (one mapped CasADi call for all samples): :func:`project` (minimum-norm
Gauss-Newton onto the targets; the coarse-to-fine warm start and the final polish) and
:func:`valid_samples` (the vectorised :meth:`PathContext.why`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import casadi as ca
import numpy as np
import numpy.typing as npt

from planner.beam.graph import system_params
from planner.model.status import Failure, Reason
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.model.validity import MIN_AHEAD, MIN_FRONT, MIN_ROI_MARGIN
from planner.path.nlp import (
    Chain,
    PathNlp,
    PathOptions,
    compiled,
    constraint_lower_bounds,
    path_nlp,
    sample_function,
    solve_window,
    step_function,
    tangents,
    tangents_batch,
)
from planner.verify.tolerances import JOINT_SLACK, Tolerances

Indices = Sequence[int] | npt.NDArray[np.integer[Any]]  # sample indices


def _constraint_failure(i: int, n_robots: int) -> tuple[Reason, str]:
    """Reason and wording of violated row ``i`` of h: ROI (2N rows), front face (N), mirror
    ahead (N), target ahead (1), incidence (1) (:func:`planner.path.nlp.constraint_lower_bounds`)."""
    if i < 2 * n_robots:
        return Reason.OUTSIDE_ROI, "ROI"
    if i < 3 * n_robots:
        return Reason.BACK_FACE, "front face"
    if i < 4 * n_robots:
        return Reason.UNREACHABLE, "mirror behind"
    if i == 4 * n_robots:
        return Reason.UNREACHABLE, "target behind"
    return Reason.UNREACHABLE, "incidence"


class SeedResult(Protocol):
    """A :class:`Seeder`'s answer: stacked joints ``q`` (rad), or None with the failure
    ``reason`` and its ``evidence``."""

    @property
    def q(self) -> Array | None: ...
    @property
    def reason(self) -> Reason | None: ...
    @property
    def evidence(self) -> dict[str, object]: ...


class Seeder(Protocol):
    """A configuration for one sample from scratch: the one nearest ``q_prev`` (stacked rad)
    that puts the spot on ``target`` (world, m; on its plane when ``normal`` is given) with
    the last ray within ``max_incidence`` (rad) of the normal. The planning pipeline passes
    the IK's closed-form family search, its members filtered by the safety rules
    (:func:`planner.plan.scenario_planner.path_seeder`); the path never imports the IK."""

    def search(self, target: Array, normal: Array | None, q_prev: Array,
               max_incidence: float | None = None) -> SeedResult: ...  # fmt: skip


class PathContext:
    """Numbers of one planning call: system geometry, targets, plane normals, bounds, and
    the ``seeder`` of a sample from scratch (None: a multi-start one-sample NLP)."""

    def __init__(
        self, system: System, targets: Targets, opts: PathOptions, seeder: Seeder | None = None
    ) -> None:
        self.system, self.opts = system, opts
        self.kin: Chain = tuple(r.kinematics for r in system.robots)
        self.step = compiled(step_function(self.kin))
        self.geo = {name: ca.DM(x) for name, x in system_params(system).items()}
        self.P = np.asarray(targets.points, dtype=float)
        K = len(self.P)
        nrm = targets.normals if targets.normals is not None else np.full((K, 3), np.nan)
        self.has = np.all(np.isfinite(nrm), axis=1)
        self.nbar = np.where(self.has[:, None], nrm, np.nan)
        self.lower, self.upper = system.lower, system.upper
        self.lbh = constraint_lower_bounds(system.n_robots, K, self.has, opts)
        self.valid_lbh = validity_bounds(self.lbh, opts)
        self.N = system.n_robots
        self.max_inc = float(np.radians(opts.max_incidence_deg))
        self.seeder = seeder

    def eval(self, k: int, q: Array, nbar: Array) -> list[Array]:
        """The step function's outputs (``path_step``: g, Jg, r, Jr, h, dir, spot) at sample
        k from joints ``q`` with target-plane normal ``nbar``."""
        args = {**self.geo, "q": q, "target": self.P[k], "nbar": nbar,
                "has_normal": float(self.has[k]), "tangents": tangents(nbar)}  # fmt: skip
        out = self.step.call([args[name] for name in self.step.name_in()])
        return [x.full() for x in out]

    def plane(self, k: int, q_near: Array) -> Array:
        """The target plane normal of sample k: its normal, or the reversed arriving beam."""
        if self.has[k]:
            return np.asarray(self.nbar[k], dtype=float)
        if np.all(np.isfinite(self.nbar[k])):
            return np.asarray(self.nbar[k], dtype=float)
        _, _, _, _, _, direction, _ = self.eval(k, q_near, np.array([0.0, 0.0, 1.0]))
        return -direction.ravel()

    def why(self, k: int, q: Array, g: Array, h: Array) -> Failure | None:
        """None if q is a valid solution of sample k, else the reason with its evidence."""
        N, lb, tol = self.N, self.valid_lbh[k], JOINT_SLACK
        bad = np.flatnonzero(~(h.ravel() >= lb))
        if not np.all(np.isfinite(q)) or np.linalg.norm(g) > max(1e3 * self.opts.tolerance, 1e-7):
            return Failure(Reason.UNREACHABLE, f"spot error {np.linalg.norm(g):.2e} m")
        if np.any(q < self.lower - tol) or np.any(q > self.upper + tol):
            j = int(np.argmax(np.maximum(self.lower - q, q - self.upper)))
            return Failure(Reason.JOINT_LIMITS, f"joint {j} at {q[j]:.3f} rad")
        if bad.size:
            i = int(bad[0])
            reason, what = _constraint_failure(i, N)
            return Failure(reason, f"{what} (constraint {i}: {h.ravel()[i]:.3g} < {lb[i]:.3g})")
        return None

    def newton(self, k: int, q0: Array, nbar: Array, iters: int = 8, centring: float = 1e-3
               ) -> tuple[Array, Failure | None]:  # fmt: skip
        """Equality-constrained Newton steps toward sample k with a centring pull (weight
        ``centring`` on the squared ROI-normalised hit offsets, first step only; 0 gives the
        minimum-norm correction of ``q0``)."""
        q, beta, nq = np.array(q0, dtype=float), centring, len(q0)
        for it in range(iters):
            beta = beta if it == 0 else 0.0  # centring in the predictor step only
            g, Jg, r, Jr, h, _, _ = self.eval(k, q, nbar)
            g = g.ravel()
            if np.linalg.norm(g) < self.opts.tolerance * 0.1:
                break
            H = np.eye(nq) + beta * Jr.T @ Jr
            KKT = np.block([[H, Jg.T], [Jg, np.zeros((2, 2))]])
            rhs = np.concatenate([-beta * Jr.T @ r.ravel(), -g])
            try:
                dq = np.linalg.solve(KKT, rhs)[:nq]
            except np.linalg.LinAlgError:
                return q, Failure(Reason.UNREACHABLE, "singular beam Jacobian")
            if np.linalg.norm(dq) > 0.5:
                dq *= 0.5 / np.linalg.norm(dq)
            q = q + dq
        g, _, _, _, h, _, _ = self.eval(k, q, nbar)
        return q, self.why(k, q, g, h)

    def seed(self, k: int, guesses: list[Array]) -> tuple[Array, Array, Failure | None]:
        """A valid configuration for sample k from scratch: the :class:`Seeder`'s when there
        is one and it finds one, else a multi-start single-sample NLP."""
        best: tuple[Array, Array, Failure | None] | None = None
        normal = self.nbar[k] if self.has[k] else None
        if self.seeder is not None:
            res = self.seeder.search(self.P[k], normal, guesses[0], self.max_inc)
            if res.q is None and res.reason is not None:
                failure = Failure(res.reason, str(res.evidence))
                best = (guesses[0], self.plane(k, guesses[0]), failure)
            elif res.q is not None:
                nbar = self.plane(k, res.q)
                q, why = self.newton(k, res.q, nbar)
                if why is None:
                    return q, nbar, None
                best = (q, nbar, why)
        nlp = path_nlp(self.kin, 1, False, self.opts.max_iter)
        for q0 in guesses:
            nbar = self.plane(k, q0)
            Q, _ = self.solve(nlp, [k], q0[None, :], nbar[None, :], (0.0, 0.0, 1e-2, 1.0, 1.0))
            q, why = self.newton(k, Q[0], self.plane(k, Q[0]))
            if why is None:
                return q, self.plane(k, Q[0]), None
            best = best or (q, nbar, why)
        assert best is not None
        return best

    def solve(self, nlp: PathNlp, ks: list[int], Q0: Array, NB: Array,
              weights: tuple[float, ...], cuts: tuple[Array, Array] | None = None,
              ) -> tuple[Array, dict[str, Any]]:  # fmt: skip
        """Run the NLP on samples ``ks`` from ``Q0`` (len(ks) x nq), with clearance rows
        ``cuts`` if it was built with them; returns (Q, IPOPT stats)."""
        return solve_window(nlp, self.system, self.P[ks], self.has[ks], self.lbh[ks], Q0, NB,
                            weights, cuts)  # fmt: skip


def continuation_chain(
    ctx: PathContext, q_start: Array, ks: Indices | None = None
) -> tuple[Array, Array, list[Failure | None]]:
    """Per-sample warm start: seeds where needed, Newton continuation forward, backward
    extension after a re-seed. ``ks``: the sample indices to walk (default all, in order).
    Returns (q len(ks) x nq with NaN, nbar len(ks) x 3, reason per walked sample)."""
    idx = list(range(len(ctx.P))) if ks is None else [int(k) for k in ks]
    K, nq = len(idx), len(q_start)
    Q = np.full((K, nq), np.nan)
    NB = np.array(ctx.nbar[idx], dtype=float)
    why: list[Failure | None] = [None] * K
    ok = np.zeros(K, dtype=bool)
    stride = max(1, K // 50)
    last = np.asarray(q_start, dtype=float)
    i = 0
    while i < K:
        q, nb, reason = ctx.seed(idx[i], [last, np.asarray(q_start, dtype=float)])
        if reason is not None:
            why[i] = reason
            i += 1 if i == 0 or ok[i - 1] else stride
            continue
        Q[i], NB[i], ok[i] = q, nb, True
        j = i - 1  # backward extension into the gap before this seed
        while j >= 0 and not ok[j]:
            nb = ctx.plane(idx[j], Q[j + 1])
            q, reason = ctx.newton(idx[j], Q[j + 1], nb)
            if reason is not None:
                why[j] = reason
                break
            Q[j], NB[j], ok[j], why[j] = q, nb, True, None
            j -= 1
        i += 1
        while i < K:  # forward continuation
            pred = 2 * Q[i - 1] - Q[i - 2] if i >= 2 and ok[i - 2] else Q[i - 1]
            nb = ctx.plane(idx[i], Q[i - 1])
            q, reason = ctx.newton(idx[i], pred, nb)
            if reason is not None:
                why[i] = reason
                last = Q[i - 1]
                i += 1
                break
            Q[i], NB[i], ok[i] = q, nb, True
            i += 1
    for i in range(K):  # samples skipped inside a gap take the nearest attempted reason
        if not ok[i] and why[i] is None:
            tried = [j for j in range(K) if why[j] is not None]
            nearest = why[min(tried, key=lambda j: abs(j - i))] if tried else None
            why[i] = nearest or Failure(Reason.UNREACHABLE, "no configuration was tried here")
    return Q, NB, why


def project(
    ctx: PathContext, ks: Indices, Q0: Array, NB: Array | None = None, iters: int = 8
) -> tuple[Array, Array, Array]:
    """Minimum-norm Gauss-Newton onto "spot on sample k", all samples ``ks`` at once.

    One mapped CasADi call per iteration; each sample steps ``dq = -Jg^T (Jg Jg^T)^-1 g``
    (the smallest joint change that zeroes the 2-vector spot offset g on the target plane)
    and keeps a step only where it lowers |g|. ``NB``: target-plane normals (default: the
    sample's normal, else the reversed arriving beam at ``Q0``). Returns (Q, NB, |g| in m).
    """
    ks = np.asarray(ks, dtype=int)
    n, nq = len(ks), Q0.shape[1]
    F = ctx.step.map(n)
    P, has = ctx.P[ks].T, ctx.has[ks][None, :].astype(float)

    def run(Q: Array, nb: Array) -> tuple[Array, Array, Array]:
        out = F(q=Q.T, **ctx.geo, target=P, nbar=nb.T, has_normal=has, tangents=tangents_batch(nb))
        Jg = np.asarray(out["Jg"], dtype=float).reshape(2, n, nq).transpose(1, 0, 2)
        return np.asarray(out["g"], dtype=float).T, Jg, np.asarray(out["dir"], dtype=float).T

    Q = np.array(Q0, dtype=float)
    if NB is None:
        NB = np.where(ctx.has[ks][:, None], ctx.nbar[ks], np.array([0.0, 0.0, 1.0]))
        NB = np.where(ctx.has[ks][:, None], NB, -run(Q, NB)[2])
    g, J, _ = run(Q, NB)
    err = np.linalg.norm(g, axis=1)
    for _ in range(iters):
        todo = err > 1e-16
        if not todo.any():
            break
        y = np.linalg.solve(J @ J.transpose(0, 2, 1), g[:, :, None])
        dq = -(J.transpose(0, 2, 1) @ y)[:, :, 0]
        dq[~todo | ~np.isfinite(dq).all(axis=1)] = 0.0
        g2, J2, _ = run(Q + dq, NB)
        err2 = np.linalg.norm(g2, axis=1)
        better = np.isfinite(err2) & (err2 < err)
        if not better.any():
            break
        Q[better] += dq[better]
        g[better], J[better], err[better] = g2[better], J2[better], err2[better]
    return Q, NB, err


def validity_bounds(lbh: Array, opts: PathOptions, slack: float = 1e-7) -> Array:
    """Lower bounds of h (K x (4N+2)) a valid sample must meet: the NLP's bounds less
    ``slack`` (m; ROI margin, front, mirror and target ahead keep most of the NLP's design
    margins and never drop below the beam-chain rule of :mod:`planner.model.validity`), and
    for the incidence the limit plus the checker's
    :data:`~planner.verify.tolerances.INCIDENCE_SLACK`, exactly as ``beamrelay check`` accepts it."""
    N = (lbh.shape[1] - 2) // 4
    floor = np.concatenate([np.full(2 * N, MIN_ROI_MARGIN), np.full(N, MIN_FRONT),
                            np.full(N, MIN_AHEAD), [MIN_AHEAD]])  # fmt: skip
    out = lbh - slack
    out[:, :-1] = np.maximum(out[:, :-1], floor)  # never below the beam-chain rule
    inc = Tolerances(max_incidence=float(np.radians(opts.max_incidence_deg)))
    out[:, -1] = np.where(np.isfinite(lbh[:, -1]), inc.min_cos_incidence, -np.inf)
    return out


def valid_samples(ctx: PathContext, ks: Indices, Q: Array, NB: Array) -> Array:
    """Which rows of ``Q`` are valid solutions of samples ``ks`` (vectorised
    :meth:`PathContext.why`: spot on target, joint limits, every reflection constraint)."""
    ks = np.asarray(ks, dtype=int)
    has = ctx.has[ks][None, :].astype(float)
    out = compiled(sample_function(ctx.kin)).map(len(ks))(
        q=Q.T, **ctx.geo, target=ctx.P[ks].T, nbar=NB.T, has_normal=has,
        tangents=tangents_batch(NB),
    )  # fmt: skip
    G, H = np.asarray(out["g"], dtype=float).T, np.asarray(out["h"], dtype=float).T
    tol = JOINT_SLACK
    ok = np.linalg.norm(G, axis=1) <= max(1e3 * ctx.opts.tolerance, 1e-7)
    ok &= np.all(ctx.lower - tol <= Q, axis=1) & np.all(ctx.upper + tol >= Q, axis=1)
    ok &= np.all(ctx.valid_lbh[ks] <= H, axis=1)
    return np.asarray(ok & np.all(np.isfinite(Q), axis=1), dtype=bool)


def coarse_indices(n: int, spacing: float, coarse_spacing: float) -> npt.NDArray[np.intp]:
    """Sample indices 0..n-1 about ``coarse_spacing`` apart (ends included), for a run of n
    samples ``spacing`` m apart."""
    m = max(1, round(coarse_spacing / max(spacing, 1e-12)))
    return np.unique(np.concatenate([np.arange(0, n, m), [n - 1]]))
