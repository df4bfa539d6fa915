"""Beam checks: through an arm, into keep-out, target in keep-out, back into the laser or
the camera; distances against the independent numpy geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.model.system import System
from planner.model.transforms import look_at, make_T, rot_x
from planner.safety import (
    PartKind,
    SafetyWorld,
    beam_arm,
    beam_keep_out,
    beam_points,
    camera_lens,
    laser_return,
    sphere,
    target_keep_out,
    violations,
)
from planner.safety.shapes import Volume
from planner.verify import arms
from planner.verify.distances import point_sphere, segment_segment, segment_sphere
from tests.planner.safety.worlds import UPRIGHT, parallel_slack, relay, single

Q2 = np.r_[UPRIGHT, UPRIGHT]


def _mirror_pose(system: System, q: np.ndarray, k: int = 0) -> np.ndarray:
    r = system.robots[k]
    return r.world_T_base @ arms.link_frames(q)[7] @ r.mirror.flange_T_mirror


def _aimed(system: System, q: np.ndarray, tilt: float) -> System:
    """The system with its laser 0.5 m in front of mirror 0, aimed at its centre ``tilt``
    rad off its normal."""
    M = _mirror_pose(system, q)
    d = M[:3, :3] @ (rot_x(tilt) @ np.array([0.0, 0.0, 1.0]))
    laser = look_at(M[:3, 3] + 0.5 * d, M[:3, 3])
    return System(laser, system.robots, system.camera)


def test_beam_through_the_other_arm_is_occluded_with_evidence():
    system = relay()
    w = SafetyWorld(system)
    w.update(Q2)
    upper = next(p for p in w.parts if p.name == "arm1/upper_arm")
    centre = w.placement(upper.index).getTranslation()
    hit0 = beam_points(w, Q2, centre)[1]
    end = centre + 0.3 * (centre - hit0) / np.linalg.norm(centre - hit0)
    pts = np.array([system.world_T_laser[:3, 3], hit0, end])
    bad = violations(beam_arm(w, Q2, pts))
    assert bad and bad[0].b == "arm1/upper_arm" and bad[0].segment == 1
    assert bad[0].check.reason == "occluded"
    assert bad[0].distance == pytest.approx(-0.054, abs=1e-9)  # through the axis: -radius


def test_own_mirror_and_mount_do_not_block_a_valid_reflection():
    system = single()
    sys_ = _aimed(system, UPRIGHT, np.radians(20))
    w = SafetyWorld(sys_)
    hit = beam_points(w, UPRIGHT, np.zeros(3))[1]
    M = _mirror_pose(sys_, UPRIGHT)
    np.testing.assert_allclose(hit, M[:3, 3], atol=1e-12)
    out_dir = M[:3, :3] @ (rot_x(-np.radians(20)) @ np.array([0.0, 0.0, 1.0]))
    pts = np.array([sys_.world_T_laser[:3, 3], hit, hit + 0.5 * out_dir])
    records = beam_arm(w, UPRIGHT, pts)
    assert all(r.b != "arm0/mirror" for r in records)  # own mirror: touched by construction
    mount = [r for r in records if r.b == "arm0/mount"]
    assert len(mount) == 2 and all(r.required == 0.0 and r.distance > 0 for r in mount)
    assert not violations(records)
    # the same beam with the mirror treated as an obstacle would touch it (distance 0)
    plate = next(p for p in w.parts if p.name == "arm0/mirror")
    from planner.safety.beam import distance, segment_shape

    seg, T = segment_shape(pts[1], pts[2])
    assert distance(seg, T, w.geometry(plate.index), w.placement(plate.index))[0] < 1e-9


segs = st.lists(st.floats(-1.2, 1.2, allow_nan=False), min_size=6, max_size=6).map(np.array)


@settings(max_examples=20, deadline=None)
@given(segs)
def test_beam_to_capsule_distances_match_numpy(s):
    system = relay()
    w = SafetyWorld(system)
    pts = np.array([s[:3], s[3:] + np.array([0.0, 0.0, 0.5])])
    if np.linalg.norm(pts[1] - pts[0]) < 1e-3:
        return
    caps = {
        c[0]: c
        for c in arms.arm_shapes(
            np.eye(4), UPRIGHT, system.robots[0].mirror.flange_T_mirror, (0.075, 0.075)
        ).capsules
    }
    got = {r.b: r for r in beam_arm(w, Q2, pts)}
    for name, (_, a, b, r, _) in caps.items():
        d = segment_segment(pts[0], pts[1], a, b)[0] - r
        tol = parallel_slack(pts[0], pts[1], a, b)
        assert got[f"arm0/{name}"].distance == pytest.approx(d, abs=tol)


def test_beam_into_keep_out_sphere_and_target_inside():
    system = single()
    eye = sphere("eye", 0.016, make_T(p=[0.4, 0.1, 0.3]))
    w = SafetyWorld(system, keep_out=[eye])
    pts = np.array([[0.0, 0.0, 0.3], [0.8, 0.2, 0.3]])  # passes the eye centre's line at 0
    rec = beam_keep_out(w, pts)
    d_np = segment_sphere(pts[0], pts[1], np.array([0.4, 0.1, 0.3]), 0.016)[0]
    assert rec[0].distance == pytest.approx(d_np, abs=1e-9) and d_np < 0
    assert violations(rec)[0].b == "keep_out/eye" and rec[0].check.reason == "keep_out"
    clear = np.array([[0.0, 0.0, 0.4], [0.8, 0.2, 0.4]])
    assert not violations(beam_keep_out(w, clear))
    targets = np.array([[0.4, 0.1, 0.3], [0.41, 0.1, 0.3], [0.4, 0.1, 0.5]])
    rec = target_keep_out(w, targets)
    expect = [point_sphere(x, np.array([0.4, 0.1, 0.3]), 0.016)[0] for x in targets]
    np.testing.assert_allclose([r.distance for r in rec], expect, atol=1e-9)
    assert [r.a for r in violations(rec)] == ["target[0]", "target[1]"]


def test_target_inside_keep_out_mesh_hull(tmp_path):
    import open3d as o3d

    path = tmp_path / "cube.ply"
    mesh = o3d.geometry.TriangleMesh.create_box(100, 100, 100).translate([-50, -50, -50])
    o3d.io.write_triangle_mesh(str(path), mesh)
    v = Volume("block", "mesh", make_T(p=[0.5, 0.5, 0.5]), (), path, 0.001)
    w = SafetyWorld(single(), keep_out=[v])
    assert w.parts_of(PartKind.KEEP_OUT)[0].name == "keep_out/block"
    rec = target_keep_out(w, np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.7]]))
    assert rec[0].distance == pytest.approx(-0.05, abs=1e-6)
    assert rec[1].distance == pytest.approx(0.15, abs=1e-6)


def test_retro_reflection_into_the_laser():
    back = _aimed(single(), UPRIGHT, 0.0)  # normal incidence: the beam returns
    w = SafetyWorld(back)
    laser = back.world_T_laser[:3, 3]
    pts = beam_points(w, UPRIGHT, laser + 0.2 * (laser - _mirror_pose(back, UPRIGHT)[:3, 3]))
    hits = laser_return(back.world_T_laser, pts)
    assert len(hits) == 1 and hits[0].segment == 1
    assert hits[0].distance < 1e-9 and hits[0].angle < 1e-6
    assert hits[0].reason == "keep_out" and "laser aperture" in str(hits[0])
    # 20 deg off the normal the reflection leaves 40 deg away from the laser
    tilted = _aimed(single(), UPRIGHT, np.radians(20))
    w = SafetyWorld(tilted)
    pts = beam_points(w, UPRIGHT, np.zeros(3))
    out = pts[1] + 0.8 * (pts[1] - pts[0]) / np.linalg.norm(pts[1] - pts[0])
    assert not laser_return(tilted.world_T_laser, pts)
    assert not laser_return(tilted.world_T_laser, np.array([pts[0], pts[1], out]))


def test_beam_into_the_camera_lens():
    cam = look_at([1.0, 0.0, 0.5], [0.0, 0.0, 0.5])  # looks along -x
    into = np.array([[0.0, 0.0, 0.3], [0.2, 0.0, 0.5], [1.2, 0.0, 0.5]])
    hits = camera_lens(cam, into)
    assert len(hits) == 1 and hits[0].segment == 1 and hits[0].angle < 1e-9
    beside = into + np.array([0.0, 0.05, 0.0])
    assert not camera_lens(cam, beside)
    away = into[::-1]  # same line, travelling away from the lens
    assert not camera_lens(cam, away)


def test_bad_polylines_are_rejected():
    w = SafetyWorld(single())
    for bad in (np.zeros((1, 3)), np.zeros((3, 2)), np.full((2, 3), np.nan)):
        with pytest.raises(ValueError):
            beam_arm(w, UPRIGHT, bad)
