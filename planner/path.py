"""Path tracking: one IPOPT NLP over all K samples of a spot path (SPEC section 4, issue 5).

Unknowns are the stacked joints ``q_k`` (all robots) at every path sample k. Constraints per
sample: the spot on the sample (2 equalities: the spot's offset from the target projected on
two tangents of the target plane; without a normal the plane is perpendicular to the
arriving beam, so "spot on the plane = target" is "ray through the target"), every reflection
valid (ROI, front face, mirror ahead, target ahead), incidence within ``max_incidence_deg``
where a normal is given, joint position limits. Objective: smoothness along the arc length
(sum of squared first and second joint differences) plus mirror centring.

Cheap to build: the per-sample SX function is built once per robot chain, the NLP once per
(chain, K, closed) with every number (geometry, targets, weights) an NLP parameter, the
sample function ``map``-ed over K inside an MX graph that is never expanded.

Warm start: a per-sample continuation chain (Newton steps with a centring pull from the
previous sample), seeded by a single-sample solve from ``q_start``. Where the chain finds no
valid configuration the path is split: each feasible run is solved separately and each gap
is reported with where (samples, arc length, point) and why.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from planner.beam import beam_chain, system_params
from planner.kinematics import RobotKinematics
from planner.system import System, Targets
from planner.transforms import Array

Chain = tuple[RobotKinematics, ...]


@dataclass(frozen=True)
class PathOptions:
    """Solver settings. Weights act on integrals over the arc length s (metres)."""

    tolerance: float = 1e-9  # spot error (m) the equality constraints are solved to
    max_iter: int = 200
    max_incidence_deg: float = 80.0
    min_front: float = 0.02  # -n.v >= this: beam at most ~89 deg from the mirror normal
    weight_velocity: float = 1.0  # integral |dq/ds|^2 ds
    weight_acceleration: float = 1e-5  # integral |d2q/ds2|^2 ds
    weight_centring: float = 0.05  # integral |uv / roi_half|^2 ds
    weight_reference: float = 1e-4  # integral |q - q_warm|^2 ds (regularises redundancy)
    verbose: bool = False


class PathGap(NamedTuple):
    """Samples ``k0 <= k < k1`` (arc length s0..s1 m, starting at world point ``p``) have no
    valid configuration; ``reason`` is a SPEC status reason, ``detail`` the evidence."""

    k0: int
    k1: int
    s0: float
    s1: float
    p: Array
    reason: str
    detail: str


class PathSegment(NamedTuple):
    """A feasible run of samples ``k0 <= k < k1`` solved by one NLP."""

    k0: int
    k1: int
    status: str  # IPOPT return status, or "warm_start" if the NLP failed and the chain is kept
    iterations: int
    solve_time: float  # s, IPOPT only
    build_time: float  # s, NLP construction (0 when cached)


@dataclass(frozen=True)
class PathResult:
    """Joints per sample (``q``: K x nq, NaN in gaps), per-sample spot error (m) and validity."""

    q: Array
    ok: Array  # (K,) bool
    error: Array  # (K,) m
    arc: Array  # (K,) cumulative arc length of the samples, m
    segments: tuple[PathSegment, ...]
    gaps: tuple[PathGap, ...]
    warm_time: float  # s, chain + seed
    nlp_time: float  # s, build + solve of every segment

    @property
    def complete(self) -> bool:
        return not self.gaps


# ------------------------------------------------------------------------------------------
# symbolic pieces (built once per chain)
# ------------------------------------------------------------------------------------------
_SAMPLE_IN = ["q", "world_T_laser", "world_T_base", "flange_T_mirror", "roi_half"]
_SAMPLE_IN += ["target", "nbar", "has_normal", "tangents"]


def _sample_exprs(kinematics: Chain) -> tuple[list[ca.SX], dict[str, ca.SX]]:
    N = len(kinematics)
    nq = sum(k.nq for k in kinematics)
    q = ca.SX.sym("q", nq)
    wTl = ca.SX.sym("world_T_laser", 4, 4)
    wTb = ca.SX.sym("world_T_base", 4, 4 * N)
    fTm = ca.SX.sym("flange_T_mirror", 4, 4 * N)
    roi_half = ca.SX.sym("roi_half", 2, N)
    target, nbar = ca.SX.sym("target", 3), ca.SX.sym("nbar", 3)
    has, E = ca.SX.sym("has_normal"), ca.SX.sym("tangents", 3, 2)
    bases = [wTb[:, 4 * i : 4 * i + 4] for i in range(N)]
    mounts = [fTm[:, 4 * i : 4 * i + 4] for i in range(N)]
    hits, uvs, dirs, fronts, aheads, _ = beam_chain(q, wTl, bases, mounts, kinematics)
    p, v = hits[-1], dirs[-1]
    s = ca.dot(nbar, target - p) / ca.dot(nbar, v)
    spot = p + s * v
    uv = ca.horzcat(*uvs)
    r = ca.vec(uv / roi_half)
    h = ca.vertcat(
        ca.vec(roi_half - ca.fabs(uv)), ca.vertcat(*fronts), ca.vertcat(*aheads), s,
        has * (-ca.dot(v, nbar)) + (1 - has),
    )  # fmt: skip
    out = {"g": ca.mtimes(E.T, spot - target), "h": h, "r": r, "dir": v, "spot": spot}
    return [q, wTl, wTb, fTm, roi_half, target, nbar, has, E], out


@lru_cache(maxsize=16)
def sample_function(kinematics: Chain) -> ca.Function:
    """Per-sample constraints: g (2, spot offset on the target plane, m), h (4N+2: ROI
    margins (m), front (-n.v), ahead (m), target ahead (m), cos incidence), centring cost."""
    ins, out = _sample_exprs(kinematics)
    c = ca.sumsqr(out["r"])
    return ca.Function("path_sample", ins, [out["g"], out["h"], c], _SAMPLE_IN, ["g", "h", "c"])


@lru_cache(maxsize=16)
def step_function(kinematics: Chain) -> ca.Function:
    """Per-sample values and Jacobians for the continuation chain."""
    ins, out = _sample_exprs(kinematics)
    q = ins[0]
    names = ["g", "Jg", "r", "Jr", "h", "dir", "spot"]
    outs = [out["g"], ca.jacobian(out["g"], q), out["r"], ca.jacobian(out["r"], q)]
    return ca.Function(
        "path_step", ins, [*outs, out["h"], out["dir"], out["spot"]], _SAMPLE_IN, names
    )


@lru_cache(maxsize=16)
def sample_hessian(kinematics: Chain) -> ca.Function:
    """Per-sample Hessian (nq x nq) of lam . [g; h] + w_c * centring with respect to q."""
    ins, out = _sample_exprs(kinematics)
    q = ins[0]
    lam = ca.SX.sym("lam", 2 + out["h"].size1())
    wc = ca.SX.sym("wc")
    L = ca.dot(lam, ca.vertcat(out["g"], out["h"])) + wc * ca.sumsqr(out["r"])
    H = ca.hessian(L, q)[0]
    return ca.Function(
        "path_hess", [*ins, lam, wc], [ca.densify(H)], [*_SAMPLE_IN, "lam", "wc"], ["H"]
    )


def _smoothness_hessians(nq: int, K: int, closed: bool) -> tuple[ca.DM, ca.DM]:
    """Constant Hessians of sum |dQ|^2 and sum |d2Q|^2 (2 D^T D, kron I_nq), sparse."""
    import scipy.sparse as sp

    C = sp.diags([-np.ones(K), np.ones(K - 1)], [0, 1], shape=(K, K), format="lil")
    if closed:
        C[K - 1, 0] = 1.0
        D1 = C.tocsr()
        D2 = D1 @ D1
    else:
        D1 = C.tocsr()[: K - 1]
        D2 = C.tocsr()[: K - 2, : K - 1] @ D1
    out = []
    for D in (D1, D2):
        M = sp.kron(2.0 * (D.T @ D), sp.eye(nq)).tocsc()
        M.sort_indices()
        spx = ca.Sparsity(M.shape[0], M.shape[1], M.indptr.tolist(), M.indices.tolist())
        out.append(ca.DM(spx, M.data.tolist()))
    return out[0], out[1]


class _Nlp(NamedTuple):
    solver: ca.Function
    n_h: int
    build_time: float


@lru_cache(maxsize=8)
def path_nlp(kinematics: Chain, K: int, closed: bool, max_iter: int = 200) -> _Nlp:
    """The IPOPT solver for K samples; parameters packed by :func:`_pack_params`."""
    t0 = time.perf_counter()
    N = len(kinematics)
    nq = sum(k.nq for k in kinematics)
    F = sample_function(kinematics)
    Q = ca.MX.sym("Q", nq, K)
    syms = {
        "world_T_laser": ca.MX.sym("wTl", 4, 4),
        "world_T_base": ca.MX.sym("wTb", 4, 4 * N),
        "flange_T_mirror": ca.MX.sym("fTm", 4, 4 * N),
        "roi_half": ca.MX.sym("roi", 2, N),
        "target": ca.MX.sym("T", 3, K),
        "nbar": ca.MX.sym("NB", 3, K),
        "has_normal": ca.MX.sym("HAS", 1, K),
        "tangents": ca.MX.sym("E", 3, 2 * K),
        "q_ref": ca.MX.sym("QREF", nq, K),
        "weights": ca.MX.sym("w", 5),  # w_vel, w_acc, w_centre, w_ref, ds
    }
    geo = [ca.repmat(syms[n], 1, K) for n in _SAMPLE_IN[1:5]]
    G, H, C = F.map(K)(Q, *geo, syms["target"], syms["nbar"], syms["has_normal"], syms["tangents"])
    w = syms["weights"]
    ds = w[4]
    dQ = ca.horzcat(Q[:, 1:] - Q[:, :-1], Q[:, :1] - Q[:, -1:]) if closed else Q[:, 1:] - Q[:, :-1]
    if closed:
        d2Q = ca.horzcat(dQ[:, 1:] - dQ[:, :-1], dQ[:, :1] - dQ[:, -1:])
    else:
        d2Q = dQ[:, 1:] - dQ[:, :-1]
    f = w[0] / ds * ca.sumsqr(dQ) + w[1] / ds**3 * ca.sumsqr(d2Q)
    f += ds * (w[2] * ca.sum2(C) + w[3] * ca.sumsqr(Q - syms["q_ref"]))
    p = ca.vertcat(*[ca.vec(s) for s in syms.values()])
    opts: dict[str, Any] = {
        "ipopt": {
            "print_level": 0,
            "sb": "yes",
            "max_iter": max_iter,
            "tol": 1e-8,
            "acceptable_tol": 1e-6,
            "mu_strategy": "adaptive",
            "warm_start_init_point": "yes",
            "mu_init": 1e-4,
            "bound_push": 1e-9,
            "bound_frac": 1e-9,
        },
        "print_time": False,
    }
    g = ca.vec(ca.vertcat(G, H))
    x = ca.vec(Q)
    # Hessian of the Lagrangian, assembled: constant smoothness band + mapped per-sample blocks
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.size1())
    LG = ca.reshape(lam_g, g.size1() // K, K)
    wc = ca.repmat(lam_f * w[2] * ds, 1, K)
    B = sample_hessian(kinematics).map(K)(Q, *geo, *[syms[n] for n in _SAMPLE_IN[5:]], LG, wc)
    blocks = ca.MX(ca.diagcat(*[ca.Sparsity.dense(nq, nq)] * K), ca.vec(B))
    M1, M2 = _smoothness_hessians(nq, K, closed) if K > 1 else (ca.DM(nq, nq), ca.DM(nq, nq))
    Hl = blocks + lam_f * (w[0] / ds * M1 + w[1] / ds**3 * M2 + 2 * w[3] * ds * ca.DM.eye(nq * K))
    hess = ca.Function("path_hess_lag", [x, p, lam_f, lam_g], [ca.triu(Hl)])
    opts["hess_lag"] = hess
    problem: dict[str, Any] = {"x": x, "p": p, "f": f, "g": g}
    solver = ca.nlpsol("path_nlp", "ipopt", problem, opts)
    return _Nlp(solver, int(H.size1()), time.perf_counter() - t0)


def _pack_params(system: System, T: Array, NB: Array, HAS: Array, E: Array, QREF: Array,
                 weights: Array) -> Array:  # fmt: skip
    """Column-major packing matching ``path_nlp``'s parameter vector (arrays K-major)."""
    geo = system_params(system)
    parts = [geo[n] for n in _SAMPLE_IN[1:5]]
    parts += [T.T, NB.T, HAS[None, :], np.concatenate(list(E), axis=1), QREF.T, weights]
    return np.concatenate([np.asarray(a, dtype=float).ravel(order="F") for a in parts])


def _bounds_h(n_robots: int, K: int, has: Array, opts: PathOptions) -> Array:
    """Lower bounds of h per sample (K x (4N+2))."""
    lb = np.concatenate(
        [np.full(2 * n_robots, 1e-6), np.full(n_robots, opts.min_front), np.full(n_robots, 1e-3),
         [1e-3], [np.cos(np.radians(opts.max_incidence_deg))]]
    )  # fmt: skip
    out = np.tile(lb, (K, 1))
    out[~has.astype(bool), -1] = -np.inf
    return out


def tangents(n: Array) -> Array:
    """Two unit vectors spanning the plane perpendicular to unit ``n`` (3 x 2)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(n, e1)])


def arc_length(points: Array, closed: bool = False) -> Array:
    """Cumulative arc length (m) of a polyline's vertices, starting at 0."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample_polyline(points: Array, spacing: float, closed: bool = False,
                      normals: Array | None = None) -> tuple[Array, Array | None]:  # fmt: skip
    """Points every ~``spacing`` m along a polyline (vertices interpolated linearly; equal
    spacing that divides the length exactly; a closed path does not repeat its start)."""
    P = np.asarray(points, dtype=float)
    Nn = None if normals is None else np.asarray(normals, dtype=float)
    if closed:
        P = np.vstack([P, P[:1]])
        Nn = None if Nn is None else np.vstack([Nn, Nn[:1]])
    s = arc_length(P)
    n = max(1, int(np.ceil(s[-1] / spacing - 1e-9)))
    s_new = np.linspace(0.0, s[-1], n + 1)[: n if closed else n + 1]
    out = np.column_stack([np.interp(s_new, s, P[:, i]) for i in range(3)])
    if Nn is None:
        return out, None
    nn = np.column_stack([np.interp(s_new, s, Nn[:, i]) for i in range(3)])
    return out, nn / np.linalg.norm(nn, axis=1, keepdims=True)


# ------------------------------------------------------------------------------------------
# warm start: seed + continuation chain
# ------------------------------------------------------------------------------------------
def _closed_form(system: System) -> Any:
    """The IK engineer's closed-form family search for this system, if it applies."""
    try:
        from planner.ik.closed_form import ClosedForm
    except ImportError:
        return None
    try:
        return ClosedForm(system)
    except ValueError:  # some robot has no analytic seed model
        return None


class _Ctx:
    """Numbers of one planning call: system geometry, targets, plane normals, bounds."""

    def __init__(self, system: System, targets: Targets, opts: PathOptions) -> None:
        self.system, self.opts = system, opts
        self.kin: Chain = tuple(r.kinematics for r in system.robots)
        self.step = step_function(self.kin)
        geo = system_params(system)
        self.geo = [ca.DM(geo[n]) for n in _SAMPLE_IN[1:5]]
        self.P = np.asarray(targets.points, dtype=float)
        K = len(self.P)
        nrm = targets.normals if targets.normals is not None else np.full((K, 3), np.nan)
        self.has = np.all(np.isfinite(nrm), axis=1)
        self.nbar = np.where(self.has[:, None], nrm, np.nan)
        self.lower, self.upper = system.lower, system.upper
        self.lbh = _bounds_h(system.n_robots, K, self.has, opts)
        self.N = system.n_robots
        self.max_inc = float(np.radians(opts.max_incidence_deg))
        self.closed_form = _closed_form(system)

    def eval(self, k: int, q: Array, nbar: Array) -> list[Array]:
        E = tangents(nbar)
        out = self.step.call([ca.DM(q), *self.geo, self.P[k], nbar, float(self.has[k]), E])
        return [np.asarray(o, dtype=float) for o in out]

    def plane(self, k: int, q_near: Array) -> Array:
        """The target plane normal of sample k: its normal, or the reversed arriving beam."""
        if self.has[k]:
            return np.asarray(self.nbar[k], dtype=float)
        if np.all(np.isfinite(self.nbar[k])):
            return np.asarray(self.nbar[k], dtype=float)
        out = self.eval(k, q_near, np.array([0.0, 0.0, 1.0]))
        return -out[5].ravel()

    def why(self, k: int, q: Array, g: Array, h: Array) -> str | None:
        """None if q is a valid solution of sample k, else a SPEC reason with evidence."""
        N, lb, tol = self.N, self.lbh[k], 1e-7
        bad = np.flatnonzero(h.ravel() < lb - tol)
        if not np.all(np.isfinite(q)) or np.linalg.norm(g) > max(1e3 * self.opts.tolerance, 1e-7):
            return f"unreachable: spot error {np.linalg.norm(g):.2e} m"
        if np.any(q < self.lower - tol) or np.any(q > self.upper + tol):
            j = int(np.argmax(np.maximum(self.lower - q, q - self.upper)))
            return f"joint_limits: joint {j} at {q[j]:.3f} rad"
        if bad.size:
            i = int(bad[0])
            kind = (
                "outside_roi"
                if i < 2 * N
                else "back_face"
                if i < 3 * N
                else "unreachable: mirror behind"
                if i < 4 * N
                else "unreachable: target behind"
                if i == 4 * N
                else "unreachable: incidence"
            )
            return f"{kind} (constraint {i}: {h.ravel()[i]:.3g} < {lb[i]:.3g})"
        return None

    def newton(self, k: int, q0: Array, nbar: Array, iters: int = 8) -> tuple[Array, str | None]:
        """Equality-constrained Newton steps toward sample k with a centring pull (1/m^2)."""
        q, beta, nq = np.array(q0, dtype=float), 1e-3, len(q0)
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
                return q, "unreachable: singular beam Jacobian"
            if np.linalg.norm(dq) > 0.5:
                dq *= 0.5 / np.linalg.norm(dq)
            q = q + dq
        g, _, _, _, h, _, _ = self.eval(k, q, nbar)
        return q, self.why(k, q, g, h)

    def seed(self, k: int, guesses: list[Array]) -> tuple[Array, Array, str | None]:
        """A valid configuration for sample k from scratch: the closed-form family search of
        :mod:`planner.ik.closed_form` when available, else a multi-start single-sample NLP."""
        best: tuple[Array, Array, str | None] | None = None
        normal = self.nbar[k] if self.has[k] else None
        if self.closed_form is not None:
            res = self.closed_form.search(self.P[k], normal, guesses[0], self.max_inc)
            if res.q is None:
                best = (guesses[0], self.plane(k, guesses[0]), f"{res.reason}: {res.evidence}")
            else:
                nbar = self.plane(k, res.q)
                q, why = self.newton(k, res.q, nbar)
                if why is None:
                    return q, nbar, None
                best = (q, nbar, why)
        nlp = path_nlp(self.kin, 1, False, self.opts.max_iter)
        for q0 in guesses:
            nbar = self.plane(k, q0)
            Q, _ = self._solve(nlp, [k], q0[None, :], nbar[None, :], (0.0, 0.0, 1e-2, 1.0, 1.0))
            q, why = self.newton(k, Q[0], self.plane(k, Q[0]))
            if why is None:
                return q, self.plane(k, Q[0]), None
            best = best or (q, nbar, why)
        assert best is not None
        return best

    def _solve(self, nlp: _Nlp, ks: list[int], Q0: Array, NB: Array,
               weights: tuple[float, ...]) -> tuple[Array, ca.Function]:  # fmt: skip
        """Run the NLP on samples ``ks`` from ``Q0`` (len(ks) x nq); returns (Q, solver)."""
        K = len(ks)
        E = np.stack([tangents(n) for n in NB])
        p = _pack_params(
            self.system, self.P[ks], NB, self.has[ks].astype(float), E, Q0, np.array(weights)
        )
        nh = nlp.n_h
        lbg = np.column_stack([np.zeros((K, 2)), self.lbh[ks]]).ravel()
        ubg = np.column_stack([np.zeros((K, 2)), np.full((K, nh), np.inf)]).ravel()
        sol = nlp.solver(
            x0=Q0.ravel(), p=p, lbx=np.tile(self.lower, K), ubx=np.tile(self.upper, K),
            lbg=lbg, ubg=ubg,
        )  # fmt: skip
        return np.asarray(sol["x"], dtype=float).reshape(K, -1), nlp.solver


def _chain(ctx: _Ctx, q_start: Array) -> tuple[Array, Array, list[str | None]]:
    """Per-sample warm start: seeds where needed, Newton continuation forward, backward
    extension after a re-seed. Returns (q K x nq with NaN, nbar K x 3, reason per sample)."""
    K, nq = len(ctx.P), len(q_start)
    Q = np.full((K, nq), np.nan)
    NB = np.array(ctx.nbar, dtype=float)
    why: list[str | None] = [None] * K
    ok = np.zeros(K, dtype=bool)
    stride = max(1, K // 50)
    last = np.asarray(q_start, dtype=float)
    k = 0
    while k < K:
        q, nb, reason = ctx.seed(k, [last, np.asarray(q_start, dtype=float)])
        if reason is not None:
            why[k] = reason
            k += 1 if k == 0 or ok[k - 1] else stride
            continue
        Q[k], NB[k], ok[k] = q, nb, True
        j = k - 1  # backward extension into the gap before this seed
        while j >= 0 and not ok[j]:
            nb = ctx.plane(j, Q[j + 1])
            q, reason = ctx.newton(j, Q[j + 1], nb)
            if reason is not None:
                why[j] = reason
                break
            Q[j], NB[j], ok[j], why[j] = q, nb, True, None
            j -= 1
        k += 1
        while k < K:  # forward continuation
            pred = 2 * Q[k - 1] - Q[k - 2] if k >= 2 and ok[k - 2] else Q[k - 1]
            nb = ctx.plane(k, Q[k - 1])
            q, reason = ctx.newton(k, pred, nb)
            if reason is not None:
                why[k] = reason
                last = Q[k - 1]
                k += 1
                break
            Q[k], NB[k], ok[k] = q, nb, True
            k += 1
    for i in range(K):  # samples skipped inside a gap take the nearest attempted reason
        if not ok[i] and why[i] is None:
            tried = [j for j in range(K) if why[j] is not None]
            why[i] = why[min(tried, key=lambda j: abs(j - i))] if tried else "unreachable"
    return Q, NB, why


def _runs(mask: Array) -> list[tuple[int, int]]:
    """Half-open index ranges of consecutive True values."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def sample_errors(system: System, Q: Array, points: Array, normals: Array | None) -> Array:
    """SPEC spot error (m) of every sample through the beam function (NaN rows -> NaN)."""
    from planner.beam import beam_function

    f = beam_function(tuple(r.kinematics for r in system.robots))
    K = len(Q)
    geo = system_params(system)
    nrm = np.zeros((K, 3)) if normals is None else np.nan_to_num(np.asarray(normals, float))
    good = np.all(np.isfinite(Q), axis=1)
    err = np.full(K, np.nan)
    if good.any():
        n = int(good.sum())
        out = f.map(n)(Q[good].T, *geo.values(), points[good].T, nrm[good].T)
        err[good] = np.asarray(out[9], dtype=float).ravel()
    return err


def plan_path(
    system: System,
    targets: Targets,
    q_start: Array | None = None,
    solver_options: PathOptions | dict[str, object] | None = None,
) -> PathResult:
    """Joint configurations sweeping the spot along ``targets`` (resampled path, world frame).

    ``q_start`` (stacked joints, default the robots' home) seeds the first sample. Infeasible
    stretches are reported as :class:`PathGap` and the feasible runs solved separately.
    """
    opts = (
        solver_options if isinstance(solver_options, PathOptions)
        else PathOptions(**(solver_options or {}))  # type: ignore[arg-type]
    )  # fmt: skip
    q_start = system.home if q_start is None else np.asarray(q_start, dtype=float)
    ctx = _Ctx(system, targets, opts)
    K, P = len(ctx.P), ctx.P
    arc = arc_length(P)
    t0 = time.perf_counter()
    Q, NB, why = _chain(ctx, q_start)
    warm_time = time.perf_counter() - t0
    ok = np.all(np.isfinite(Q), axis=1)
    ds = float(arc[-1] / max(K - 1, 1)) or 1e-3
    weights = (opts.weight_velocity, opts.weight_acceleration, opts.weight_centring,
               opts.weight_reference, ds)  # fmt: skip
    segments, t1 = [], time.perf_counter()
    runs = _runs(ok)
    closed = bool(targets.closed) and runs == [(0, K)]
    for k0, k1 in runs:
        n = k1 - k0
        if n < 2:
            segments.append(PathSegment(k0, k1, "warm_start", 0, 0.0, 0.0))
            continue
        cached = path_nlp.cache_info().hits
        nlp = path_nlp(ctx.kin, n, closed, opts.max_iter)
        build = 0.0 if path_nlp.cache_info().hits > cached else nlp.build_time
        ks = list(range(k0, k1))
        Qs, solver = ctx._solve(nlp, ks, Q[k0:k1], NB[k0:k1], weights)
        stats = solver.stats()
        status = str(stats.get("return_status", "unknown"))
        G, H, _ = sample_function(ctx.kin).map(n)(
            Qs.T, *[ca.repmat(g, 1, n) for g in ctx.geo], P[k0:k1].T, NB[k0:k1].T,
            ctx.has[k0:k1][None, :].astype(float),
            np.concatenate([tangents(nb) for nb in NB[k0:k1]], axis=1),
        )  # fmt: skip
        G, H = np.asarray(G), np.asarray(H)
        valid = all(ctx.why(k, Qs[i], G[:, i], H[:, i]) is None for i, k in enumerate(ks))
        if valid:
            Q[k0:k1] = Qs
        else:
            status = f"warm_start ({status})"
        segments.append(
            PathSegment(
                k0,
                k1,
                status,
                int(stats.get("iter_count", 0)),
                float(stats.get("t_wall_total", 0.0)),
                build,
            )
        )
    nlp_time = time.perf_counter() - t1
    gaps = []
    for k0, k1 in _runs(~ok):
        reason = str(why[k0] or "unreachable")
        s1 = float(arc[k1]) if k1 < K else float(arc[-1])
        gaps.append(PathGap(k0, k1, float(arc[k0]), s1, P[k0].copy(), reason.split(":")[0]
                            .split(" ")[0], reason))  # fmt: skip
    err = sample_errors(system, Q, P, targets.normals)
    return PathResult(Q, ok, err, arc, tuple(segments), tuple(gaps), warm_time, nlp_time)
