"""Camera-frame targets land on the surface that carries them: a target a few mm inside or
above a board is planned onto the board where its beam meets it (the point checked against a
plain-numpy line-plane intersection), one beyond the tolerance is still occluded, and neither
another object in the way nor a keep-out volume opens up."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from planner.ik import IKOptions
from planner.model.scene import SceneModel
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.plan.landing import landings, surface_tolerance
from planner.plan.scenario_planner import plan_landed_points, plan_points
from schemas.defaults import SURFACE_TOLERANCE_M
from tests.planner.ik import ik_systems as sy
from tests.planner.plan.test_occlusion import box

UP = np.array([0.0, 0.0, 1.0])
TOP = np.array([0.3, 0.3, 0.0])  # a point of the board's top face (z = 0)
BOARD = box("board", TOP - [0, 0, 0.005], [0.3, 0.3, 0.01])


def on_plane(system: System, q: Array, target: Array) -> Array:
    """Plain numpy: where the last beam segment of the free solution (through ``target``)
    meets the plane z = 0."""
    free = plan_points(system, Targets(target[None], UP[None]), IKOptions())[0]
    assert free.ok and free.hits is not None
    h = free.hits[-1]
    v = (target - h) / np.linalg.norm(target - h)
    return np.asarray(h + (-h[2] / v[2]) * v)


def test_the_tolerance_is_at_least_the_stated_minimum() -> None:
    assert surface_tolerance() == SURFACE_TOLERANCE_M == 0.015
    assert surface_tolerance(0.002) == SURFACE_TOLERANCE_M
    assert surface_tolerance(0.01) == pytest.approx(0.03)  # 3 x a 10 mm spot uncertainty


@pytest.mark.parametrize("dz", [-0.006, 0.006])
def test_a_target_off_its_board_lands_where_its_beam_meets_the_board(dz: float) -> None:
    system = sy.n1()
    requested = TOP + np.array([0.0, 0.0, dz])
    exact = Targets(requested[None], UP[None])
    scene = SceneModel([BOARD])
    [before] = plan_points(system, exact, IKOptions(), scene=scene)
    if dz < 0:  # inside the board: its own top face hides it from the beam
        assert before.reason == "occluded"
    camera = dataclasses.replace(exact, surface_tolerance=surface_tolerance())
    landed, [sol] = plan_landed_points(system, camera, IKOptions(), scene=scene)
    expected = on_plane(system, before.q if before.q is not None else system.home, requested)
    assert sol.ok and sol.error < 1e-9
    np.testing.assert_allclose(landed.points[0], expected, atol=1e-6)
    np.testing.assert_allclose(sol.spot, expected, atol=1e-6)
    ev = sol.evidence["surface"]
    assert ev["object"] == "board"
    np.testing.assert_allclose(ev["requested"], requested, atol=1e-12)
    dist = float(np.linalg.norm(expected - requested))
    assert ev["offset_m"] == pytest.approx(dist if dz > 0 else -dist, abs=1e-6)
    assert abs(dz) < dist  # along the slanted beam: farther than the depth


def test_a_target_deeper_than_the_tolerance_stays_occluded() -> None:
    system = sy.n1()
    deep = Targets((TOP - [0, 0, 0.008])[None], UP[None], surface_tolerance=0.005)
    landed, [sol] = plan_landed_points(system, deep, IKOptions(), scene=SceneModel([BOARD]))
    assert sol.reason == "occluded" and "surface" not in sol.evidence
    np.testing.assert_array_equal(landed.points, deep.points)


def test_another_object_in_front_still_occludes_the_target() -> None:
    """A slab 10 mm over the whole board: the target 4 mm inside the board is carried by
    the board (nearer), every beam to it crosses the slab first."""
    system = sy.n1()
    slab = box("slab", TOP + np.array([0, 0, 0.06]), [0.6, 0.6, 0.1])
    scene = SceneModel([BOARD, slab])
    target = Targets((TOP - [0, 0, 0.004])[None], UP[None], surface_tolerance=0.015)
    sols = plan_points(system, target, IKOptions())
    assert landings(scene, target, sols, 0.015) == {}  # the beam meets the slab first
    _, [sol] = plan_landed_points(system, target, IKOptions(), scene=scene)
    assert sol.reason == "occluded"
    assert sol.evidence["occluded"]["object"] == "slab"


def plane_cloud(rng: np.random.Generator, noise: float = 0.0005, half: float = 0.03) -> Array:
    """A camera's cloud of the plane z = 0 around :data:`TOP`: 1.5 mm pitch, ``noise`` m
    depth noise."""
    u = np.arange(-half, half + 1e-9, 0.0015)
    x, y = np.meshgrid(u, u)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]) + TOP
    pts[:, 2] += rng.normal(0.0, noise, len(pts))
    return pts


@pytest.mark.parametrize("dz", [-0.006, 0.004])
def test_a_target_off_the_live_cloud_lands_on_the_surface_the_cloud_shows(dz: float) -> None:
    """No scene object: the cloud around the target is the surface. The landing point lies
    on the plane z = 0 where the beam meets it (numpy line-plane intersection) to within the
    plane fit's error (0.5 mm depth noise averaged over ~30 points), not at the target's own
    depth."""
    from planner.plan.landing import CLOUD

    rng = np.random.default_rng(4)
    system = sy.n1()
    requested = TOP + np.array([0.0, 0.0, dz])
    camera = Targets(requested[None], UP[None], surface_tolerance=surface_tolerance(),
                     cloud=plane_cloud(rng))  # fmt: skip
    landed, [sol] = plan_landed_points(system, camera, IKOptions())
    [before] = plan_points(system, Targets(requested[None], UP[None]), IKOptions())
    assert before.q is not None
    expected = on_plane(system, before.q, requested)
    assert sol.ok and sol.error < 1e-9
    assert sol.evidence["surface"]["object"] == CLOUD
    assert np.linalg.norm(landed.points[0] - expected) < 3e-4
    assert sol.evidence["surface"]["offset_m"] == pytest.approx(
        float(np.linalg.norm(expected - requested)) * np.sign(dz), abs=3e-4)  # fmt: skip


def test_the_cloud_carries_no_target_where_it_is_no_surface() -> None:
    """Scattered points (no plane), too few points, a target beyond the tolerance, one the
    scene already carries: no cloud landing."""
    from types import SimpleNamespace

    from planner.plan.landing import cloud_landings

    rng = np.random.default_rng(5)
    flat = plane_cloud(rng, noise=0.0)
    start = TOP + np.array([0.0, -0.2, 0.4])  # the last mirror: the beam comes from there
    sol = SimpleNamespace(ok=True, hits=start[None])

    def land(cloud: Array, target: Array, skip: frozenset[int] = frozenset()) -> dict[int, object]:
        return cloud_landings(cloud, Targets(target[None]), [sol], 0.015, skip)  # type: ignore[list-item]

    assert set(land(flat, TOP + np.array([0, 0, -0.005]))) == {0}
    blob = TOP + rng.uniform(-0.01, 0.01, (3000, 3))  # foliage, hair: no plane there
    assert land(blob, TOP) == {}
    assert land(flat[::200], TOP) == {}  # a handful of points is no surface
    assert land(flat, TOP + np.array([0, 0, -0.03])) == {}  # 30 mm: beyond the tolerance
    assert land(flat, TOP, frozenset({0})) == {}
