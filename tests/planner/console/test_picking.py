"""Picking: the click ray's cloud point against the analytic ray-plane hit; the SVD normal
against the known plane."""

from __future__ import annotations

import numpy as np
import pytest

from planner.console.picking import fit_plane, pick_point, surface_normal
from planner.errors import InputError


def plane_cloud(normal: np.ndarray, centre: np.ndarray, half: float, step: float,
                sigma: float, seed: int = 0) -> np.ndarray:  # fmt: skip
    """A square grid on the plane through ``centre`` with unit ``normal``, noise ``sigma``
    along the normal (m)."""
    n = normal / np.linalg.norm(normal)
    a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    u, v = np.meshgrid(np.arange(-half, half + 1e-12, step), np.arange(-half, half + 1e-12, step))
    P = centre + u.reshape(-1, 1) * a + v.reshape(-1, 1) * b
    return P + sigma * np.random.default_rng(seed).standard_normal((len(P), 1)) * n


def test_the_pick_is_the_cloud_point_at_the_ray_plane_intersection() -> None:
    n, c = np.array([0.0, 0.0, 1.0]), np.array([-0.49, -0.55, -0.06])
    cloud = plane_cloud(n, c, 0.15, 0.002, 0.0005)
    rng = np.random.default_rng(1)
    for _ in range(20):
        target = c + np.array([*rng.uniform(-0.1, 0.1, 2), 0.0])
        eye = np.array([-1.2, -1.3, 0.8])
        d = (target - eye) / np.linalg.norm(target - eye)
        pick = pick_point(cloud, eye, d)
        assert pick is not None
        # the ray meets the plane z = -0.06 at `target`; grid step 2 mm, noise 0.5 mm
        assert np.linalg.norm(pick.p[:2] - target[:2]) < 0.004
        assert abs(pick.p[2] - c[2]) < 0.003
        assert np.array_equal(pick.p, cloud[pick.row])


def test_the_first_surface_along_the_ray_wins() -> None:
    front = plane_cloud(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.1]), 0.05, 0.002, 0.0)
    back = plane_cloud(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.0]), 0.05, 0.002, 0.0)
    cloud = np.vstack([back, front])  # the farther surface first in memory
    pick = pick_point(cloud, np.array([0.001, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))
    assert pick is not None and pick.p[2] == pytest.approx(0.1)


def test_a_ray_that_misses_or_points_away_picks_nothing() -> None:
    cloud = plane_cloud(np.array([0.0, 0.0, 1.0]), np.zeros(3), 0.05, 0.002, 0.0)
    assert pick_point(cloud, np.array([0.5, 0.5, 1.0]), np.array([0.0, 0.0, -1.0])) is None
    assert pick_point(cloud, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])) is None
    assert pick_point(np.zeros((0, 3)), np.zeros(3), np.array([0.0, 0.0, 1.0])) is None


@pytest.mark.parametrize(
    ("origin", "direction"),
    [([0, 0, 1], [0, 0, 0]), ([np.nan, 0, 1], [0, 0, -1]), ([0, 0, 1], [np.inf, 0, -1])],
)
def test_a_bad_ray_is_an_input_error(origin: list[float], direction: list[float]) -> None:
    cloud = plane_cloud(np.array([0.0, 0.0, 1.0]), np.zeros(3), 0.05, 0.002, 0.0)
    with pytest.raises(InputError, match="not a ray"):
        pick_point(cloud, np.array(origin, float), np.array(direction, float))


def test_svd_normal_of_an_exact_plane_is_exact_and_faces_the_viewer() -> None:
    rng = np.random.default_rng(2)
    for _ in range(10):
        n = rng.standard_normal(3)
        n /= np.linalg.norm(n)
        c = rng.uniform(-1, 1, 3)
        cloud = plane_cloud(n, c, 0.02, 0.002, 0.0)
        viewer = c - 0.7 * n  # behind the plane's n side: the normal must flip toward it
        fit = surface_normal(cloud, c, viewer)
        assert np.allclose(fit.normal, -n, atol=1e-10)
        assert fit.rms < 1e-12
        fit = surface_normal(cloud, c, c + 0.5 * n)
        assert np.allclose(fit.normal, n, atol=1e-10)


def test_svd_normal_of_a_noisy_d435_like_plane() -> None:
    """1.3 mm depth noise (D435 at ~0.6 m) on a 2 mm grid: a 10 mm-radius fit (~75 points)
    has a normal within a few degrees and an rms near the noise."""
    n = np.array([0.3, -0.2, 0.93])
    n /= np.linalg.norm(n)
    cloud = plane_cloud(n, np.zeros(3), 0.05, 0.002, 0.0013, seed=3)
    fit = surface_normal(cloud, np.zeros(3), n)
    angle = np.degrees(np.arccos(np.clip(fit.normal @ n, -1, 1)))
    assert angle < 8.0
    assert 0.0008 < fit.rms < 0.0016
    assert 60 < fit.n_points < 90


def test_too_few_neighbours_and_too_few_points_are_input_errors() -> None:
    with pytest.raises(InputError, match="within 10 mm"):
        surface_normal(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.zeros(3), np.ones(3))
    with pytest.raises(InputError, match=">= 3 points"):
        fit_plane(np.zeros((2, 3)))


def test_a_noisy_pick_moved_onto_the_fitted_plane_is_near_the_true_surface() -> None:
    """Depth noise 1.3 mm: the raw cloud point is off the board by ~1 sigma, the plane of
    its neighbours by a few tenths of a mm (an independent check: the known plane z = -0.06)."""
    n, c = np.array([0.0, 0.0, 1.0]), np.array([-0.49, -0.55, -0.06])
    cloud = plane_cloud(n, c, 0.05, 0.002, 0.0013, seed=5)
    raw, snap = [], []
    for k in range(0, len(cloud), 97):
        fit = surface_normal(cloud, cloud[k], c + np.array([0, 0, 1.0]))
        snapped = fit.project(cloud[k])
        assert abs(float((snapped - fit.centroid) @ fit.normal)) < 1e-12  # on the fitted plane
        assert np.linalg.norm((snapped - cloud[k])[:2]) < 1e-3  # moved along the normal only
        raw.append(abs(cloud[k][2] - c[2]))
        snap.append(abs(snapped[2] - c[2]))
    assert np.median(raw) > 0.0006 and np.median(snap) < 0.0004 and max(snap) < 0.0015
