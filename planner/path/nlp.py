"""The path-tracking NLP: one IPOPT problem over all K samples of a spot path.

Unknowns are the stacked joints ``q_k`` (all robots) at every path sample k. Constraints per
sample: the spot on the sample (2 equalities: the spot's offset from the target projected on
two tangents of the target plane; without a normal the plane is perpendicular to the
arriving beam, so "spot on the plane = target" is "ray through the target"), every reflection
valid (ROI, front face, mirror ahead, target ahead), incidence within ``max_incidence_deg``
where a normal is given, joint position limits. Objective: smoothness along the arc length
(sum of squared first and second joint differences) plus mirror centring.

Cheap to build: the per-sample SX function is built once per robot chain, the NLP once per
(chain, K, closed) with every number (geometry, targets, weights) an NLP parameter, the
sample function ``map``-ed over K inside an MX graph that is never expanded. The Hessian of
the Lagrangian is assembled from the constant smoothness band and mapped per-sample blocks.

With ``cuts`` > 0 every sample also carries that many clearance rows ``A_k q_k >= lb_k``
(linearised safety distances, :mod:`planner.safety.linearize`): the row matrices are the
last parameter (``cuts`` x nq*K, sample-major), the bounds come with the call, unused rows
zero with bound -inf; their Jacobian is the block diagonal of the A_k, their Hessian zero.

The warm start lives in :mod:`planner.path.warm`, the public entry in :mod:`planner.path.solve`.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from planner.beam.graph import ChainSymbols, beam_chain, chain_symbols, system_params
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
from planner.model.system import System
from planner.model.transforms import Array, plane_bases, plane_basis

Chain = tuple[RobotKinematics, ...]
Surfaces = tuple[Surface, ...]  # each mirror's face, chain order: with Chain, the cache key


@dataclass(frozen=True)
class PathOptions:
    """Solver settings. Weights act on integrals over the arc length s (metres)."""

    tolerance: float = 1e-9  # spot error (m) the equality constraints are solved to
    max_iter: int = 200
    max_incidence_deg: float = 80.0
    min_front: float = 0.02  # -n.v >= this: beam at most ~89 deg from the mirror normal
    weight_velocity: float = 1.0  # integral |dq/ds|^2 ds
    weight_acceleration: float = 1e-6  # integral |d2q/ds2|^2 ds (m^2: ~1 mm correlation)
    weight_centring: float = 0.05  # integral |uv / roi_half|^2 ds
    weight_reference: float = (
        1.0  # integral |q - q_warm|^2 ds: posture (the warm start is seeded nearest home)
    )
    acceleration_spacing: float = 1e-3  # m: finer spacing scales weight_acceleration by (ds/this)^2
    coarse_spacing: float = 5e-3  # m: finer paths are warm-started from every m-th sample
    polish: bool = True  # final per-sample min-norm Gauss-Newton to machine precision


GEOMETRY = tuple(name for name in ChainSymbols._fields if name != "q")
SAMPLE_DATA = ("target", "nbar", "has_normal", "tangents")
SAMPLE_INPUTS = (*ChainSymbols._fields, *SAMPLE_DATA)
#: the path NLP's parameter vector, in packing order (:func:`pack_params`)
PATH_PARAMETERS = (*GEOMETRY, *SAMPLE_DATA, "q_ref", "weights")


def _sample_exprs(
    kinematics: Chain, surfaces: Surfaces
) -> tuple[dict[str, ca.SX], dict[str, ca.SX]]:
    """Per-sample inputs (by :data:`SAMPLE_INPUTS` name) and the expressions built on them."""
    sym = chain_symbols(kinematics)
    target, nbar = ca.SX.sym("target", 3), ca.SX.sym("nbar", 3)
    has, E = ca.SX.sym("has_normal"), ca.SX.sym("tangents", 3, 2)
    hits, uvs, dirs, fronts, aheads, _ = beam_chain(
        sym.q, sym.world_T_laser, sym.bases, sym.mounts, kinematics, surfaces
    )
    p, v = hits[-1], dirs[-1]
    s = ca.dot(nbar, target - p) / ca.dot(nbar, v)
    spot = p + s * v
    uv = ca.horzcat(*uvs)
    r = ca.vec(uv / sym.roi_half)
    h = ca.vertcat(
        ca.vec(sym.roi_half - ca.fabs(uv)), ca.vertcat(*fronts), ca.vertcat(*aheads), s,
        has * (-ca.dot(v, nbar)) + (1 - has),
    )  # fmt: skip
    out = {"g": ca.mtimes(E.T, spot - target), "h": h, "r": r, "dir": v, "spot": spot}
    ins = sym._asdict() | {"target": target, "nbar": nbar, "has_normal": has, "tangents": E}
    return ins, out


def _function(name: str, ins: dict[str, ca.SX], outs: dict[str, ca.SX]) -> ca.Function:
    """A CasADi function with named inputs and outputs, in the dicts' order."""
    return ca.Function(name, ins | outs, list(ins), list(outs))


@lru_cache(maxsize=16)
def sample_function(kinematics: Chain, surfaces: Surfaces) -> ca.Function:
    """Per-sample constraints: g (2, spot offset on the target plane, m), h (4N+2: ROI
    margins (m), front (-n.v), ahead (m), target ahead (m), cos incidence), centring cost."""
    ins, out = _sample_exprs(kinematics, surfaces)
    return _function("path_sample", ins, {"g": out["g"], "h": out["h"], "c": ca.sumsqr(out["r"])})


@lru_cache(maxsize=16)
def step_function(kinematics: Chain, surfaces: Surfaces) -> ca.Function:
    """Per-sample values and Jacobians for the continuation chain."""
    ins, out = _sample_exprs(kinematics, surfaces)
    q = ins["q"]
    outs = {"g": out["g"], "Jg": ca.jacobian(out["g"], q), "r": out["r"],
            "Jr": ca.jacobian(out["r"], q), "h": out["h"], "dir": out["dir"], "spot": out["spot"]}  # fmt: skip
    return _function("path_step", ins, outs)


def compiled(f: ca.Function) -> ca.Function:
    """``f`` compiled to C (CasADi code generation, ``cc -O1``), cached on disk under
    ``$XDG_CACHE_HOME/beamrelay`` by a hash of the generated source; ``f`` itself when no C
    compiler works or the cache is not writable. About 4x faster per call than the SX
    virtual machine; only for functions the NLP does not differentiate further. Kept in
    memory per (function, compiler, cache directory): generating the source to hash it costs
    ~10 ms a call, and a plan builds several path contexts."""

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return f
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "beamrelay"
    return _compiled(f, cc, str(cache))


@lru_cache(maxsize=64)
def _compiled(f: ca.Function, cc: str, cache_dir: str) -> ca.Function:
    """:func:`compiled` with the compiler and cache directory resolved (cached in memory)."""

    gen = f"{f.name()}_gen"
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator(gen)
        cg.add(f)
        cg.generate(tmp + os.sep)
        src = Path(tmp, gen + ".c").read_bytes()
    cache = Path(cache_dir)
    lib = cache / f"{f.name()}_{hashlib.sha256(src).hexdigest()[:16]}.so"
    if not lib.exists():
        tmp_c, tmp_lib = lib.with_suffix(f".{os.getpid()}.c"), lib.with_suffix(f".{os.getpid()}")
        try:
            cache.mkdir(parents=True, exist_ok=True)
            tmp_c.write_bytes(src)
            cmd = [cc, "-O1", "-fPIC", "-shared", str(tmp_c), "-o", str(tmp_lib)]
            subprocess.run(cmd, check=True, capture_output=True, timeout=300)
            os.replace(tmp_lib, lib)  # atomic: concurrent planners never load a partial file
        except (OSError, subprocess.SubprocessError):
            return f
        finally:
            tmp_c.unlink(missing_ok=True)
            tmp_lib.unlink(missing_ok=True)
    return ca.external(f.name(), str(lib))


@lru_cache(maxsize=16)
def sample_jacobian(kinematics: Chain, surfaces: Surfaces) -> ca.Function:
    """Per-sample constraints [g; h] (2 + 4N + 2) and their dense Jacobian in q, expanded
    SX: mapped over K it gives the block-diagonal constraint Jacobian of the path NLP."""
    ins, out = _sample_exprs(kinematics, surfaces)
    gh = ca.vertcat(out["g"], out["h"])
    return _function("path_jac", ins, {"gh": gh, "J": ca.densify(ca.jacobian(gh, ins["q"]))})


@lru_cache(maxsize=16)
def sample_hessian(kinematics: Chain, surfaces: Surfaces) -> ca.Function:
    """Per-sample Hessian (nq x nq) of lam . [g; h] + w_c * centring with respect to q."""
    ins, out = _sample_exprs(kinematics, surfaces)
    lam = ca.SX.sym("lam", 2 + out["h"].size1())
    wc = ca.SX.sym("wc")
    L = ca.dot(lam, ca.vertcat(out["g"], out["h"])) + wc * ca.sumsqr(out["r"])
    H = ca.hessian(L, ins["q"])[0]
    return _function("path_hess", ins | {"lam": lam, "wc": wc}, {"H": ca.densify(H)})


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


class PathNlp(NamedTuple):
    solver: ca.Function
    n_h: int
    build_time: float
    cuts: int = 0  # clearance rows per sample


def _objective(Q: Any, C: Any, q_ref: Any, w: Any, closed: bool) -> Any:
    """Smoothness (joint steps and their differences, wrapping round on a closed path), hit
    centring and pull to the reference joints, weighted by ``w`` (w_vel, w_acc, w_centre,
    w_ref, ds)."""
    ds = w[4]
    dQ = ca.horzcat(Q[:, 1:] - Q[:, :-1], Q[:, :1] - Q[:, -1:]) if closed else Q[:, 1:] - Q[:, :-1]
    if closed:
        d2Q = ca.horzcat(dQ[:, 1:] - dQ[:, :-1], dQ[:, :1] - dQ[:, -1:])
    else:
        d2Q = dQ[:, 1:] - dQ[:, :-1]
    f = w[0] / ds * ca.sumsqr(dQ) + w[1] / ds**3 * ca.sumsqr(d2Q)
    return f + ds * (w[2] * ca.sum2(C) + w[3] * ca.sumsqr(Q - q_ref))


def _options(max_iter: int) -> dict[str, Any]:
    """IPOPT's settings for the path NLP (warm-started, quiet)."""
    ipopt = {
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
        # AMD ordering: the KKT matrix is banded; MUMPS' automatic choice spent 1.3 s of
        # symbolic analysis at K = 5000 (AMD: 0.05 s)
        "mumps_pivot_order": 0,
    }
    return {"ipopt": ipopt, "print_time": False}


@lru_cache(maxsize=8)
def path_nlp(kinematics: Chain, surfaces: Surfaces, K: int, closed: bool, max_iter: int = 200,
             cuts: int = 0) -> PathNlp:  # fmt: skip
    """The IPOPT solver for K samples; parameters packed by :func:`pack_params` (then the
    ``cuts`` clearance rows per sample, module docstring)."""
    t0 = time.perf_counter()
    nq = sum(k.nq for k in kinematics)
    F = sample_function(kinematics, surfaces)
    Q = ca.MX.sym("Q", nq, K)
    chain = chain_symbols(kinematics)
    syms = {name: ca.MX.sym(name, *getattr(chain, name).shape) for name in GEOMETRY}
    syms |= {
        "target": ca.MX.sym("target", 3, K),
        "nbar": ca.MX.sym("nbar", 3, K),
        "has_normal": ca.MX.sym("has_normal", 1, K),
        "tangents": ca.MX.sym("tangents", 3, 2 * K),
        "q_ref": ca.MX.sym("q_ref", nq, K),
        "weights": ca.MX.sym("weights", 5),  # w_vel, w_acc, w_centre, w_ref, ds
    }
    per_sample = {name: ca.repmat(syms[name], 1, K) for name in GEOMETRY}
    per_sample |= {name: syms[name] for name in SAMPLE_DATA}
    out = F.map(K)(q=Q, **per_sample)
    G, H, C = out["g"], out["h"], out["c"]
    w = syms["weights"]
    ds = w[4]
    f = _objective(Q, C, syms["q_ref"], w, closed)
    p = ca.vertcat(*[ca.vec(syms[name]) for name in PATH_PARAMETERS])
    opts = _options(max_iter)
    g: Any = ca.vec(ca.vertcat(G, H))
    x = ca.vec(Q)
    # constraint Jacobian, assembled: mapped dense per-sample blocks on the block diagonal
    jac_out = compiled(sample_jacobian(kinematics, surfaces)).map(K)(q=Q, **per_sample)
    GH, JB = jac_out["gh"], jac_out["J"]
    m = int(GH.size1())
    jac = ca.MX(ca.diagcat(*[ca.Sparsity.dense(m, nq)] * K), ca.vec(JB))
    g_all: Any = ca.vec(GH)
    jac_all: Any = jac
    if cuts:
        A = ca.MX.sym("cuts", cuts, nq * K)
        p = ca.vertcat(p, ca.vec(A))
        qs, rows = ca.MX.sym("q", nq), ca.MX.sym("A", cuts, nq)
        lin = ca.Function("clearance_rows", [rows, qs], [ca.mtimes(rows, qs)]).map(K)(A, Q)
        g = ca.vertcat(g, ca.vec(lin))
        g_all = ca.vertcat(g_all, ca.vec(lin))
        blocks_a = ca.MX(ca.diagcat(*[ca.Sparsity.dense(cuts, nq)] * K), ca.vec(A))
        jac_all = ca.vertcat(jac, blocks_a)
    opts["jac_g"] = ca.Function("path_jac_g", [x, p], [g_all, jac_all])
    # Hessian of the Lagrangian, assembled: constant smoothness band + mapped per-sample blocks
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.size1())
    LG = ca.reshape(lam_g[: m * K], m, K)
    wc = ca.repmat(lam_f * w[2] * ds, 1, K)
    B = compiled(sample_hessian(kinematics, surfaces)).map(K)(q=Q, **per_sample, lam=LG, wc=wc)["H"]
    blocks = ca.MX(ca.diagcat(*[ca.Sparsity.dense(nq, nq)] * K), ca.vec(B))
    M1, M2 = _smoothness_hessians(nq, K, closed) if K > 1 else (ca.DM(nq, nq), ca.DM(nq, nq))
    Hl = blocks + lam_f * (w[0] / ds * M1 + w[1] / ds**3 * M2 + 2 * w[3] * ds * ca.DM.eye(nq * K))
    hess = ca.Function("path_hess_lag", [x, p, lam_f, lam_g], [ca.triu(Hl)])
    opts["hess_lag"] = hess
    problem: dict[str, Any] = {"x": x, "p": p, "f": f, "g": g}
    solver = ca.nlpsol("path_nlp", "ipopt", problem, opts)
    return PathNlp(solver, int(H.size1()), time.perf_counter() - t0, cuts)


def pack_params(system: System, T: Array, NB: Array, HAS: Array, E: Array, QREF: Array,
                 weights: Array) -> Array:  # fmt: skip
    """Column-major packing of ``path_nlp``'s parameter vector, by name in
    :data:`PATH_PARAMETERS` order (arrays K-major)."""
    E = np.asarray(E, dtype=float)
    E = E if E.ndim == 2 else np.concatenate(list(E), axis=1)  # K x 3 x 2 or 3 x 2K
    values = system_params(system) | {"target": T.T, "nbar": NB.T, "has_normal": HAS[None, :],
                                      "tangents": E, "q_ref": QREF.T, "weights": weights}  # fmt: skip
    parts = [np.asarray(values[name], dtype=float).ravel(order="F") for name in PATH_PARAMETERS]
    return np.concatenate(parts)


def constraint_lower_bounds(n_robots: int, K: int, has: Array, opts: PathOptions) -> Array:
    """Lower bounds of h per sample (K x (4N+2))."""
    lb = np.concatenate(
        [np.full(2 * n_robots, 1e-6), np.full(n_robots, opts.min_front), np.full(n_robots, 1e-3),
         [1e-3], [np.cos(np.radians(opts.max_incidence_deg))]]
    )  # fmt: skip
    out = np.tile(lb, (K, 1))
    out[~has.astype(bool), -1] = -np.inf
    return out


def tangents(n: Array) -> Array:
    """Two unit vectors spanning the plane perpendicular to ``n`` (3 x 2: the in-plane axes
    of :func:`planner.model.transforms.plane_basis`)."""
    return plane_basis(n)[:, 1:]


def tangents_batch(N: Array) -> Array:
    """:func:`tangents` of every row of normals ``N`` (K x 3), as one 3 x 2K matrix
    [e1_0, e2_0, e1_1, e2_1, ...] (the layout of the NLP's ``tangents`` parameter)."""
    E = plane_bases(N)[:, :, 1:]  # K x 3 x 2
    return np.asarray(E.transpose(1, 0, 2).reshape(3, -1))


def solve_window(
    nlp: PathNlp, system: System, P: Array, has: Array, lbh: Array, Q0: Array, NB: Array,
    weights: tuple[float, ...], cuts: tuple[Array, Array] | None = None,
) -> tuple[Array, dict[str, Any]]:  # fmt: skip
    """Run ``nlp`` on the K samples ``P`` (K x 3 world targets, ``has`` which carry a normal,
    ``lbh`` K x (4N+2) lower bounds of h) from ``Q0`` (K x nq) with target-plane normals
    ``NB`` (K x 3); ``cuts``: the clearance rows ``(A K x cuts x nq, lb K x cuts)`` of an
    NLP built with ``cuts``. Returns (Q K x nq, IPOPT stats)."""
    K = len(P)
    E = tangents_batch(NB)
    p = pack_params(system, P, NB, has.astype(float), E, Q0, np.array(weights))
    nh = nlp.n_h
    lbg = np.column_stack([np.zeros((K, 2)), lbh]).ravel()
    ubg = np.column_stack([np.zeros((K, 2)), np.full((K, nh), np.inf)]).ravel()
    if nlp.cuts:
        if cuts is None or cuts[0].shape != (K, nlp.cuts, system.nq):
            raise ValueError(f"the NLP takes {nlp.cuts} clearance rows per sample for {K} samples")
        A, lb = cuts
        p = np.concatenate([p, np.concatenate(list(A), axis=1).ravel(order="F")])
        lbg = np.concatenate([lbg, np.asarray(lb, dtype=float).ravel()])
        ubg = np.concatenate([ubg, np.full(A.shape[0] * A.shape[1], np.inf)])
    sol = nlp.solver(
        x0=Q0.ravel(), p=p, lbx=np.tile(system.lower, K), ubx=np.tile(system.upper, K),
        lbg=lbg, ubg=ubg,
    )  # fmt: skip
    return np.asarray(sol["x"], dtype=float).reshape(K, -1), dict(nlp.solver.stats())
