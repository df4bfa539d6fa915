"""The CasADi beam graph vs an independent numpy tracer, reflection properties, and
finite-difference checks of its Jacobians."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.beam.graph import BeamModel, beam_function, system_params
from planner.model.system import System
from planner.model.transforms import axis_angle_to_matrix, make_T
from tests.conftest import make_system
from tests.planner.model.test_kinematics import dh_fk


def numpy_trace(system: System, q: np.ndarray, target: np.ndarray, normal: np.ndarray | None):
    """Independent tracer: DH FK, plane intersection, reflection (conventions section 3)."""
    p = system.world_T_laser[:3, 3].copy()
    v = system.world_T_laser[:3, 2].copy()
    hits, uvs = [], []
    for i, r in enumerate(system.robots):
        M = r.world_T_base @ dh_fk(q[6 * i : 6 * i + 6]) @ r.mirror.flange_T_mirror
        c, n = M[:3, 3], M[:3, 2]
        t = n @ (c - p) / (n @ v)
        h = p + t * v
        uvs.append(M[:3, :2].T @ (h - c))
        v = v - 2 * (v @ n) * n
        p = h
        hits.append(h)
    if normal is None:
        spot = p + (v @ (target - p)) * v
    else:
        spot = p + (normal @ (target - p)) / (normal @ v) * v
    return np.array(hits), np.array(uvs), v, spot


@pytest.mark.parametrize("n", [1, 2, 3])
def test_graph_matches_numpy_tracer(n: int) -> None:
    system = make_system(n, seed=n)
    model = BeamModel(system)
    rng = np.random.default_rng(n)
    for _ in range(50):
        q = system.home + rng.uniform(-0.5, 0.5, system.nq)
        target = rng.uniform(-1, 1, 3)
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        for nn in (None, normal):
            tr = model.trace(q, target, nn)
            hits, uvs, v, spot = numpy_trace(system, q, target, nn)
            np.testing.assert_allclose(tr.hits, hits, atol=1e-9, rtol=1e-9)
            np.testing.assert_allclose(tr.uv, uvs, atol=1e-9, rtol=1e-9)
            np.testing.assert_allclose(tr.dirs[-1], v, atol=1e-12)
            np.testing.assert_allclose(tr.spot, spot, atol=1e-9, rtol=1e-9)
            assert tr.error == pytest.approx(np.linalg.norm(spot - target), abs=1e-9)


def test_error_without_normal_is_distance_to_ray() -> None:
    system = make_system(1)
    model = BeamModel(system)
    tr0 = model.trace(system.home)
    p, v = tr0.hits[-1], tr0.dirs[-1]
    offset = np.cross(v, [0.0, 0.0, 1.0])
    offset *= 0.0123 / np.linalg.norm(offset)
    target = p + 0.7 * v + offset
    tr = model.trace(system.home, target)
    assert tr.error == pytest.approx(0.0123, abs=1e-12)
    assert tr.target_ahead == pytest.approx(0.7, abs=1e-12)


def test_incidence_angle_on_target_plane() -> None:
    system = make_system(1)
    model = BeamModel(system)
    tr0 = model.trace(system.home)
    v = tr0.dirs[-1]
    target = tr0.hits[-1] + 0.5 * v
    axis = np.cross(v, [1.0, 0.0, 0.0])
    axis /= np.linalg.norm(axis)
    normal = axis_angle_to_matrix(axis * np.deg2rad(35.0)) @ (-v)
    tr = model.trace(system.home, target, normal)
    assert np.degrees(tr.incidence) == pytest.approx(35.0, abs=1e-9)
    assert tr.error < 1e-12


unit = st.tuples(*[st.floats(-1, 1)] * 3).map(np.array).filter(lambda x: np.linalg.norm(x) > 0.1)


@settings(max_examples=200, deadline=None)
@given(v=unit, n=unit)
def test_reflection_properties(v: np.ndarray, n: np.ndarray) -> None:
    from planner.model.mirror import FLAT, Mirror

    v, n = v / np.linalg.norm(v), n / np.linalg.norm(n)
    T = ca.SX.sym("world_T_mirror", 4, 4)
    vs = ca.SX.sym("v", 3)
    reflect = ca.Function("r", [vs, T], [FLAT.reflect_sx(T, vs, ca.SX.zeros(3))])
    M = Mirror(np.eye(4)).place(np.zeros(3), n, np.array([1.0, 0.0, 0.0]), 0.0, np.zeros(2))

    def f(v: np.ndarray, n: np.ndarray) -> np.ndarray:
        out = np.array(reflect(v, M)).ravel()  # the CasADi twin and numpy agree
        np.testing.assert_allclose(out, Mirror(np.eye(4)).reflect(M, v, np.zeros(3)), atol=1e-15)
        return out

    r = f(v, n)
    assert np.linalg.norm(r) == pytest.approx(1.0, abs=1e-12)  # |v'| = 1
    assert abs(r @ n) == pytest.approx(abs(v @ n), abs=1e-12)  # incidence = reflection
    assert np.linalg.norm(np.cross(np.cross(v, n), n) - np.cross(np.cross(r, n), n)) < 1e-12
    twice = np.array(f(r, n)).ravel()
    np.testing.assert_allclose(twice, v, atol=1e-12)  # reflecting twice is the identity


@settings(max_examples=50, deadline=None)
@given(du=st.floats(-0.02, 0.02), dv=st.floats(-0.02, 0.02), seed=st.integers(0, 1000))
def test_moving_mirror_in_its_plane_keeps_spot(du: float, dv: float, seed: int) -> None:
    system = make_system(2, seed=seed % 7)
    rng = np.random.default_rng(seed)
    q = system.home + rng.uniform(-0.2, 0.2, system.nq)
    target = rng.uniform(-1, 1, 3)
    base = BeamModel(system).trace(q, target)
    mounts = {}
    for r in system.robots:
        shift = r.mirror.flange_T_mirror @ make_T(p=[du, dv, 0.0])
        mounts[r.name] = shift
    moved = BeamModel(system.with_params(flange_T_mirror=mounts)).trace(q, target)
    np.testing.assert_allclose(moved.spot, base.spot, atol=1e-9)
    np.testing.assert_allclose(moved.hits, base.hits, atol=1e-9)
    np.testing.assert_allclose(moved.uv, base.uv - [du, dv], atol=1e-9)


@pytest.mark.parametrize("n", [1, 2])
def test_jacobians_match_finite_differences(n: int) -> None:
    system = make_system(n, seed=3)
    f = beam_function(system.kinematics, system.surfaces)
    params = system_params(system)
    rng = np.random.default_rng(0)
    q = system.home + rng.uniform(-0.2, 0.2, system.nq)
    target, normal = rng.uniform(-1, 1, 3), np.array([0.0, 0.6, 0.8])
    args = {"q": q, **params, "target": target, "normal": normal}
    sym = dict(zip(f.name_in(), f.sx_in(), strict=True))
    out_sym = f(**sym)
    for wrt in ("q", "world_T_laser", "world_T_base", "flange_T_mirror", "target"):
        jac = ca.Function(
            "beam_jacobian",
            list(sym.values()),
            [ca.jacobian(ca.vec(out_sym[k]), ca.vec(sym[wrt])) for k in ("spot", "uv")],
            list(sym),
            ["spot", "uv"],
        )
        out = jac(**args)
        J_spot, J_uv = np.array(out["spot"]), np.array(out["uv"])
        x0 = np.asarray(args[wrt], dtype=float)
        flat = x0.ravel(order="F")  # CasADi is column-major
        eps = 1e-6
        for j in rng.choice(flat.size, size=min(flat.size, 8), replace=False):
            xp, xm = flat.copy(), flat.copy()
            xp[j] += eps
            xm[j] -= eps
            fp = f(**{**args, wrt: xp.reshape(x0.shape, order="F")})
            fm = f(**{**args, wrt: xm.reshape(x0.shape, order="F")})
            d_spot = (np.array(fp["spot"]) - np.array(fm["spot"])).ravel(order="F") / (2 * eps)
            d_uv = (np.array(fp["uv"]) - np.array(fm["uv"])).ravel(order="F") / (2 * eps)
            np.testing.assert_allclose(J_spot[:, j], d_spot, atol=2e-6, rtol=1e-5)
            np.testing.assert_allclose(J_uv[:, j], d_uv, atol=2e-6, rtol=1e-5)


def test_chain_symbols_shapes_and_blocks() -> None:
    from planner.beam.graph import chain_symbols
    from planner.model.kinematics import RobotKinematics

    kin = RobotKinematics.ur5e()
    sym = chain_symbols((kin, kin))
    assert sym.q.shape == (12, 1) and sym.world_T_laser.shape == (4, 4)
    assert sym.world_T_base.shape == (4, 8) and sym.roi_half.shape == (2, 2)
    # block i of the stacked parameters is columns 4i..4i+3
    f = ca.Function("f", [sym.world_T_base, sym.flange_T_mirror], [sym.bases[1], sym.mounts[0]])
    W, F = np.arange(32.0).reshape(4, 8), -np.arange(32.0).reshape(4, 8)
    b1, m0 = (np.asarray(x) for x in f(W, F))
    np.testing.assert_array_equal(b1, W[:, 4:8])
    np.testing.assert_array_equal(m0, F[:, 0:4])
