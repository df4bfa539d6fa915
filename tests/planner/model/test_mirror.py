"""The mirror seam: numpy Mirror, its CasADi twin and the checker's own surface agree with
hand geometry, and the planner's traces go through the seam (a different surface changes
them)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.beam.trace import trace_beam
from planner.model.mirror import FLAT, Flat, Mirror
from planner.model.transforms import Array, axis_angle_to_matrix, inv_T, make_T
from planner.verify.faces import FLAT_FACE, reflect
from tests.conftest import make_system


def _pose(seed: int) -> Array:
    rng = np.random.default_rng(seed)
    return make_T(axis_angle_to_matrix(rng.uniform(-2, 2, 3)), rng.uniform(-1, 1, 3))


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_intersect_and_reflect_match_hand_geometry(seed: int) -> None:
    M = _pose(seed)
    rng = np.random.default_rng(seed + 1)
    target = M[:3, 3] + M[:3, :2] @ rng.uniform(-0.03, 0.03, 2)  # a point on the face
    p = target - rng.uniform(0.2, 1.0) * (v := _unit(rng.normal(size=3)))
    if abs(v @ M[:3, 2]) < 0.05:
        return  # near-grazing rays are ill-conditioned for this comparison
    mirror = Mirror(np.eye(4))
    t, hit, uv = mirror.intersect(M, p, v)
    np.testing.assert_allclose(hit, target, atol=1e-12)
    np.testing.assert_allclose(hit, p + t * v, atol=1e-15)
    np.testing.assert_allclose(uv, (inv_T(M) @ np.append(hit, 1.0))[:2], atol=1e-12)
    w = mirror.reflect(M, v, hit)
    n = M[:3, 2]
    assert np.linalg.norm(w) == pytest.approx(1.0, abs=1e-12)
    assert w @ n == pytest.approx(-(v @ n), abs=1e-12)  # angle of incidence = reflection
    np.testing.assert_allclose(w - (w @ n) * n, v - (v @ n) * n, atol=1e-12)  # tangent kept
    # the CasADi twin and the checker's own flat surface give the same numbers
    T, ps, vs = ca.SX.sym("T", 4, 4), ca.SX.sym("p", 3), ca.SX.sym("v", 3)
    t_sx, h_sx, uv_sx = FLAT.intersect_sx(T, ps, vs)
    f = ca.Function("f", [T, ps, vs], [t_sx, h_sx, uv_sx, FLAT.reflect_sx(T, vs, h_sx)])
    out = [np.asarray(x).ravel() for x in f(M, p, v)]
    for a, b in zip(out, [np.atleast_1d(t), hit, uv, w], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    tc, hc, uvc = FLAT_FACE.intersect(M[None], p[None], v[None])
    np.testing.assert_allclose(np.concatenate([tc, hc[0], uvc[0]]), [t, *hit, *uv], atol=1e-12)
    np.testing.assert_allclose(reflect(FLAT_FACE, M[None], v[None], hc)[0], w, atol=1e-12)


def test_parallel_ray_misses() -> None:
    t, hit, _ = Mirror(np.eye(4)).intersect(np.eye(4), np.array([0, 0, 1.0]), np.array([1.0, 0, 0]))
    assert t == np.inf and not np.all(np.isfinite(hit))


def test_place_puts_the_hit_at_uv_with_the_normal() -> None:
    h, n = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.6, 0.8])
    T = Mirror(np.eye(4)).place(h, n, np.array([1.0, 0.0, 0.0]), 0.7, np.array([0.01, -0.02]))
    np.testing.assert_allclose(T[:3, 2], n, atol=1e-15)
    np.testing.assert_allclose((inv_T(T) @ np.append(h, 1))[:3], [0.01, -0.02, 0.0], atol=1e-15)


@dataclass(frozen=True)
class Raised(Flat):
    """A test surface: the face lies ``lift`` metres above the mirror frame's z = 0."""

    lift: float = 0.0

    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[float, Array, Array]:
        return super().intersect(world_T_mirror @ make_T(p=[0, 0, self.lift]), p, v)


def test_planner_trace_goes_through_the_seam() -> None:
    """Swapping the surface of every robot's mirror changes trace_beam exactly as moving the
    flat mirror would: the numpy trace asks the mirror's surface, it does not intersect
    planes itself."""
    system = make_system(2, seed=3)
    lift = 0.004
    raised = replace(system, robots=tuple(
        replace(r, mirror=replace(r.mirror, surface=Raised(lift=lift))) for r in system.robots
    ))  # fmt: skip
    moved = system.with_params(flange_T_mirror={
        r.name: r.mirror.flange_T_mirror @ make_T(p=[0, 0, lift]) for r in system.robots
    })  # fmt: skip
    q, target = system.home, np.array([0.2, 0.1, 0.3])
    a, b = trace_beam(raised, q, target), trace_beam(moved, q, target)
    np.testing.assert_allclose(a.hits, b.hits, atol=1e-12)
    np.testing.assert_allclose(a.spot, b.spot, atol=1e-12)
    assert np.abs(a.hits - trace_beam(system, q, target).hits).max() > 1e-3


def test_a_mirror_is_flat_unless_told() -> None:
    m = Mirror(np.eye(4))
    assert m.surface == FLAT and m.surface.is_flat and m.surface.spec == {"shape": "flat"}


def _unit(x: Array) -> Array:
    return x / np.linalg.norm(x)
