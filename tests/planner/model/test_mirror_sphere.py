"""The spherical mirror behind the seam: hand optics, its CasADi twin and the checker's own
sphere agree, and placing it puts a face point on a hit with a given normal."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.model.mirror import Mirror
from planner.model.mirror_sphere import Sphere
from planner.model.transforms import Array, axis_angle_to_matrix, inv_T, make_T
from planner.verify.faces import SphereFace, face_from_spec, reflect


def _pose(seed: int) -> Array:
    rng = np.random.default_rng(seed)
    return make_T(axis_angle_to_matrix(rng.uniform(-2, 2, 3)), rng.uniform(-1, 1, 3))


def _local(M: Array, x: Array, w: float = 1.0) -> Array:
    return (inv_T(M) @ np.append(x, w))[:3]


@pytest.mark.parametrize("R", [0.5, -0.4, 2.0])
@pytest.mark.parametrize("y0", [0.002, 0.02, 0.035])
def test_a_ray_along_the_axis_crosses_it_where_a_sphere_says(R: float, y0: float) -> None:
    """A ray parallel to the axis at height y0 meets the cap at z = R - sqrt(R^2 - y0^2) and
    leaves crossing the axis at z = R - R / (2 cos theta), sin theta = y0 / R (the spherical
    aberration formula; R/2, the paraxial focus, as y0 -> 0; virtual behind a convex face)."""
    M = _pose(7)
    surface = Sphere(R)
    p, v = M[:3, :3] @ [0.0, y0, 1.0] + M[:3, 3], -M[:3, 2]
    t, hit, uv = surface.intersect(M, p, v)
    sag = R - np.sign(R) * np.sqrt(R * R - y0 * y0)
    np.testing.assert_allclose(_local(M, hit), [0.0, y0, sag], atol=1e-14)
    np.testing.assert_allclose(uv, [0.0, y0], atol=1e-14)
    assert t == pytest.approx(1.0 - sag, abs=1e-14)
    w = _local(M, surface.reflect(M, v, hit), 0.0)
    h = _local(M, hit)
    z_cross = h[2] - h[1] / w[1] * w[2]
    cos_theta = np.sqrt(1.0 - (y0 / R) ** 2)
    assert z_cross == pytest.approx(R - R / (2 * cos_theta), abs=1e-12)
    if abs(y0 / R) < 0.01:
        assert z_cross == pytest.approx(R / 2, rel=1e-3)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), R=st.sampled_from([0.3, -0.3, 1.5, -5.0]))
def test_numpy_casadi_and_checker_spheres_agree(seed: int, R: float) -> None:
    M = _pose(seed)
    rng = np.random.default_rng(seed + 1)
    surface = Sphere(R)
    uv0 = rng.uniform(-0.03, 0.03, 2)
    target = (M @ surface.mirror_T_tangent(uv0))[:3, 3]  # a point on the face
    n0 = surface.normal(M, target)
    v = rng.normal(size=3)
    v = v / np.linalg.norm(v)
    v = v if v @ n0 < 0 else -v  # arriving on the front face
    if abs(v @ n0) < 0.1:
        return  # near-grazing: ill-conditioned, not what this compares
    p = target - rng.uniform(0.2, 1.0) * v
    t, hit, uv = surface.intersect(M, p, v)
    np.testing.assert_allclose(hit, target, atol=1e-12)
    np.testing.assert_allclose(uv, uv0, atol=1e-12)
    n = surface.normal(M, hit)
    w = surface.reflect(M, v, hit)
    assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-14)
    assert w @ n == pytest.approx(-(v @ n), abs=1e-12)
    T, ps, vs = ca.SX.sym("T", 4, 4), ca.SX.sym("p", 3), ca.SX.sym("v", 3)
    t_sx, h_sx, uv_sx = surface.intersect_sx(T, ps, vs)
    outs = [t_sx, h_sx, uv_sx, surface.normal_sx(T, h_sx), surface.reflect_sx(T, vs, h_sx)]
    got = [np.asarray(x).ravel() for x in ca.Function("f", [T, ps, vs], outs)(M, p, v)]
    for a, b in zip(got, [np.atleast_1d(t), hit, uv, n, w], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    face = face_from_spec(surface.spec)
    assert face == SphereFace(R)
    tc, hc, uvc = face.intersect(M[None], p[None], v[None])
    np.testing.assert_allclose(np.concatenate([tc, hc[0], uvc[0]]), [t, *hit, *uv], atol=1e-12)
    np.testing.assert_allclose(reflect(face, M[None], v[None], hc)[0], w, atol=1e-12)


def test_a_ray_past_the_sphere_misses() -> None:
    M, surface = np.eye(4), Sphere(0.2)
    t, hit, _ = surface.intersect(M, np.array([0.5, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))
    assert t == np.inf and not np.isfinite(hit).any()
    tc, hc, _ = SphereFace(0.2).intersect(M[None], np.array([[0.5, 0.0, 1.0]]),
                                           np.array([[0.0, 0.0, -1.0]]))  # fmt: skip
    assert tc[0] == np.inf and not np.isfinite(hc).any()


@pytest.mark.parametrize("R", [0.25, -0.25])
def test_place_puts_a_face_point_on_the_hit_with_the_normal(R: float) -> None:
    h, n = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.6, 0.8])
    mirror = Mirror(np.eye(4), surface=Sphere(R))
    uv = np.array([0.012, -0.02])
    T = mirror.place(h, n, np.array([1.0, 0.0, 0.0]), 0.7, uv)
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-14)
    local = _local(T, h)
    np.testing.assert_allclose(local[:2], uv, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(local - [0, 0, R]), abs(R), atol=1e-14)
    np.testing.assert_allclose(mirror.normal(T, h), n, atol=1e-14)
    assert not np.isfinite(mirror.place(h, n, np.array([1.0, 0, 0]), 0.0, np.array([0.3, 0]))).any()


def test_shape_depth_spec_and_bad_spheres() -> None:
    lo, hi = Sphere(0.5).depth((0.075, 0.075))
    r2 = 2 * 0.0375**2
    assert (lo, hi) == (0.0, pytest.approx(0.5 - np.sqrt(0.25 - r2), abs=1e-15))
    assert Sphere(-0.5).depth((0.075, 0.075)) == (pytest.approx(-hi, abs=1e-15), 0.0)
    assert not Sphere(0.5).is_flat and Sphere(0.5).spec == {"shape": "sphere", "radius": 0.5}
    with pytest.raises(ValueError, match=r"cannot hold a 0\.075 x 0\.075 m mirror"):
        Mirror(np.eye(4), size=(0.075, 0.075), surface=Sphere(0.05))
    with pytest.raises(ValueError, match="non-zero radius"):
        Sphere(0.0)
    with pytest.raises(Exception, match="no independent check for a mirror of shape 'cone'"):
        face_from_spec({"shape": "cone"})
