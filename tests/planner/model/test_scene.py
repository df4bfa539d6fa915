"""SceneModel: ray and segment hits against analytic box / sphere intersections, margins,
object names, the empty scene, and the camera sim sharing it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from planner.errors import InputError
from planner.model.scene import SPHERE_RESOLUTION, SceneItem, SceneModel
from planner.model.transforms import Array, inv_T, make_T, rpy_to_matrix

BOX_T = make_T(rpy_to_matrix([0.3, -0.2, 0.7]), [0.4, -0.1, 0.25])
EXTENTS = np.array([0.2, 0.1, 0.05])
SPHERE_C = np.array([-0.3, 0.2, 0.1])
RADIUS = 0.08


def box_entry(T: Array, extents: Array, p: Array, v: Array) -> float:
    """Slab method in the box frame: distance along the unit ray to the entry face (inf)."""
    Ti = inv_T(T)
    p_o, v_o = Ti[:3, :3] @ p + Ti[:3, 3], Ti[:3, :3] @ v
    half = extents / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - p_o) / v_o, (half - p_o) / v_o
    t_near, t_far = np.max(np.minimum(t1, t2)), np.min(np.maximum(t1, t2))
    return float(t_near) if t_far >= max(t_near, 0.0) and t_near > 0 else float("inf")


def sphere_entry(c: Array, r: float, p: Array, v: Array) -> float:
    """|p + t v - c| = r, smallest positive root (inf)."""
    b = float(v @ (p - c))
    disc = b * b - float((p - c) @ (p - c)) + r * r
    if disc < 0:
        return float("inf")
    t = -b - np.sqrt(disc)
    return t if t > 0 else float("inf")


BOX = SceneItem("box", "box", BOX_T, extents=EXTENTS)
BALL = SceneItem("ball", "sphere", make_T(p=SPHERE_C), radius=RADIUS)


@pytest.fixture(scope="module")
def scene() -> SceneModel:
    return SceneModel([BOX, BALL])


def rays_at(centre: Array, n: int, seed: int) -> tuple[Array, Array]:
    """Rays from 1 m around ``centre`` aimed within 0.1 m of it (about half hit)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    origins = centre + d / np.linalg.norm(d, axis=1, keepdims=True)
    aim = centre + rng.uniform(-0.1, 0.1, (n, 3))
    v = aim - origins
    return origins, v / np.linalg.norm(v, axis=1, keepdims=True)


def test_box_hits_match_the_slab_method() -> None:
    P, V = rays_at(BOX_T[:3, 3], 400, seed=1)
    hits = SceneModel([BOX]).cast(P, V)
    t_ref = np.array([box_entry(BOX_T, EXTENTS, p, v) for p, v in zip(P, V, strict=True)])
    # rays that clip an edge within 1e-5 m are ambiguous in float32; none are drawn here
    assert np.isfinite(t_ref).sum() > 100 and (~np.isfinite(t_ref)).sum() > 50
    assert np.array_equal(np.isfinite(hits.t), np.isfinite(t_ref))
    hit = np.isfinite(t_ref)
    assert np.abs(hits.t[hit] - t_ref[hit]).max() < 1e-6  # float32 at ~1 m
    assert set(hits.object[hit]) == {0} and set(hits.object[~hit]) == {-1}
    # the normal is the box face the ray enters through: opposite to the ray
    assert (np.einsum("ij,ij->i", hits.normal[hit], V[hit]) < 0).all()


def test_sphere_hits_match_the_quadratic_within_tessellation() -> None:
    P, V = rays_at(SPHERE_C, 400, seed=2)
    P, V = P[P[:, 0] < SPHERE_C[0]], V[P[:, 0] < SPHERE_C[0]]  # from the side away from the box
    hits = SceneModel([BOX, BALL]).cast(P, V)
    assert all(box_entry(BOX_T, EXTENTS, p, v) == np.inf for p, v in zip(P, V, strict=True))
    t_ref = np.array([sphere_entry(SPHERE_C, RADIUS, p, v) for p, v in zip(P, V, strict=True)])
    sag = RADIUS * (1 - np.cos(np.pi / SPHERE_RESOLUTION))  # facets lie inside the sphere
    clear = np.isfinite(t_ref) & np.isfinite(hits.t)
    assert clear.sum() > 50
    dt = hits.t[clear] - t_ref[clear]
    assert dt.min() > -1e-6  # the facets lie inside the sphere: never hit before it
    radial = np.linalg.norm(P[clear] + hits.t[clear, None] * V[clear] - SPHERE_C, axis=1)
    assert radial.max() < RADIUS + 1e-6 and radial.min() > RADIUS - sag - 1e-6
    # misses agree except grazing rays within the sag of the silhouette
    p_miss = np.isfinite(t_ref) != np.isfinite(hits.t)
    closest = np.linalg.norm(np.cross(SPHERE_C - P[p_miss], V[p_miss]), axis=1)
    assert (np.abs(closest - RADIUS) < sag).all()
    assert set(hits.object[clear]) == {1}


def test_segment_hits_distance_and_margins(scene: SceneModel) -> None:
    top = BOX_T[:3, :3] @ np.array([0, 0, EXTENTS[2] / 2]) + BOX_T[:3, 3]  # top face centre
    up = BOX_T[:3, 2]
    start = top + 0.3 * up
    assert scene.segment_hits(start, top - 0.01 * up) == pytest.approx(0.3, abs=1e-6)
    assert scene.segment_hits(start, top) is None  # ends on the surface: a target lying on it
    assert scene.segment_hits(start, top + 1e-4 * up) is None
    assert scene.segment_hits(start, top, end_margin=0.0) == pytest.approx(0.3, abs=1e-6)
    assert scene.segment_hits(start, top + 0.1 * up) is None  # stops short
    assert scene.segment_hits(top, start) is None  # leaves the surface
    # batched, with the object and the point where the segment meets it
    hits = scene.blocked_segments(
        np.array([start, SPHERE_C + 0.5 * np.array([0.0, 0.0, 1.0]), start]),
        np.array([top - 0.01 * up, SPHERE_C, top + 0.2 * up]),
    )
    assert [(h.segment, h.object) for h in hits] == [(0, "box"), (1, "ball")]
    assert np.allclose(hits[0].point, top, atol=1e-6)
    assert hits[1].distance == pytest.approx(0.5 - RADIUS, abs=1e-6)  # pole vertex is exact
    assert hits[1].length == pytest.approx(0.5)


def test_empty_scene_never_imports_open3d() -> None:
    code = (
        "import sys, numpy as np\n"
        "from planner.model.scene import SceneModel\n"
        "s = SceneModel([])\n"
        "d, o = s.segment_distances(np.zeros((5, 3)), np.ones((5, 3)))\n"
        "print(s.empty, np.isinf(d).all(), (o == -1).all(), s.segment_hits([0,0,0],[1,1,1]),"
        " 'open3d' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True", "True", "None", "False"]


def test_meshes_and_unknown_shapes() -> None:
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_box(0.1, 0.1, 0.1).translate([1.0, 0.0, 0.0])
    scene = SceneModel([SceneItem("ball", "sphere", make_T(p=SPHERE_C), radius=RADIUS)],
                       meshes=[("cube", mesh)])  # fmt: skip
    assert scene.names == ("ball", "cube")
    hits = scene.blocked_segments([0.5, 0.05, 0.05], [1.2, 0.05, 0.05])
    assert [(h.object, round(h.distance, 6)) for h in hits] == [("cube", 0.5)]
    with pytest.raises(InputError, match="unknown shape"):
        SceneModel([SceneItem("x", "torus", np.eye(4))]).cast([0, 0, 0], [0, 0, 1])


def test_camera_sim_uses_the_same_scene(scene: SceneModel) -> None:
    import open3d as o3d

    from drivers.camera.sim import build_scene

    P, V = rays_at(BOX_T[:3, 3], 50, seed=3)
    rays = np.hstack([P, V]).astype(np.float32)
    cam = build_scene(list(scene.items)).cast_rays(o3d.core.Tensor.from_numpy(rays))
    assert np.array_equal(cam["t_hit"].numpy(), scene.raycasting_scene.cast_rays(
        o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy())  # fmt: skip
