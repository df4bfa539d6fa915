"""The coal world against the independent numpy geometry, and the constructed collisions."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from planner.errors import InputError
from planner.model.build import ur5e_robot
from planner.model.mirror_sphere import Sphere
from planner.model.transforms import make_T
from planner.safety import (
    UR5E_BOXES,
    UR5E_CAPSULES,
    UR5E_SELF_EXCLUDED,
    PairKind,
    PartKind,
    SafetyWorld,
    arm_arm,
    arm_scene,
    arm_self,
    box,
    pair_clearances,
    sphere,
    violations,
    worst,
)
from planner.safety.geometry import mirror_boxes
from planner.safety.shapes import Volume
from planner.safety.ur5e import DEFAULT_MIRROR_BLOCKS
from planner.verify import arms
from planner.verify.numpy_beam import ur5e_dh_fk
from tests.planner.safety.worlds import REACH, UPRIGHT, parallel_slack, relay, single

RELAY = relay()
BOX_PARTS = {"mirror", "mount"} | {b.name for b in UR5E_BOXES}
WORLD = SafetyWorld(RELAY)


def _numpy_arms(system, q):
    qs = system.split_q(q)
    return [
        arms.arm_shapes(r.world_T_base, qs[r.name], r.mirror.flange_T_mirror, r.mirror.size)
        for r in system.robots
    ]


def test_link_tables_agree():
    ours = [(c.name, c.link, c.a, c.b, c.radius) for c in UR5E_CAPSULES]
    assert ours == list(arms.CAPSULES)
    assert [(b.name, b.link, b.centre, b.extents) for b in UR5E_BOXES] == list(arms.BOXES)
    assert {p for p in arms.SELF_EXCLUDED if p in UR5E_SELF_EXCLUDED} == set(UR5E_SELF_EXCLUDED)


def test_numpy_link_frames_match_pinocchio_joint_frames():
    q = np.random.default_rng(3).uniform(-3, 3, 12)
    WORLD.update(q)
    F = arms.link_frames(q[:6])
    for j in range(1, 7):
        np.testing.assert_allclose(WORLD.data.oMi[j].homogeneous, F[j], atol=1e-12)
    np.testing.assert_allclose(F[7], ur5e_dh_fk(q[:6]), atol=1e-12)


def test_pairs_skip_adjacent_links_and_the_flange_carrier():
    names = {
        (WORLD.parts[c.first].name, WORLD.parts[c.second].name)
        for c in WORLD.geom_model.collisionPairs
    }
    assert ("arm0/upper_arm", "arm0/forearm") not in names  # adjacent links
    assert ("arm0/base", "arm0/shoulder") not in names
    assert ("arm0/wrist_3", "arm0/mirror") not in names  # carried by wrist_3
    assert ("arm0/wrist_3", "arm0/mount") not in names
    assert ("arm0/wrist_2", "arm0/mount") in names  # the mount can hit the arm
    assert ("arm0/base", "arm0/forearm") in names
    assert ("arm0/wrist_1", "arm0/wrist_3") not in names  # excluded: envelopes always touch
    assert ("arm0/forearm", "arm0/wrist_3") in names
    assert ("arm0/mirror", "arm1/mirror") in names
    n_parts = len(UR5E_CAPSULES) + len(UR5E_BOXES) + 2
    assert WORLD.pair_kinds.count(PairKind.ARM_ARM) == n_parts**2


def _parallel_slack(a, b, key) -> float:
    caps = {}
    for k, arm in enumerate((a, b)):
        caps |= {f"arm{k}/{c[0]}": c for c in arm.capsules}
    if key[0] not in caps or key[1] not in caps:
        return 1e-9
    (_, p0, p1, _, _), (_, q0, q1, _, _) = caps[key[0]], caps[key[1]]
    return parallel_slack(p0, p1, q0, q1)


joints = st.lists(st.floats(-np.pi, np.pi, allow_nan=False), min_size=12, max_size=12).map(np.array)


@settings(max_examples=12, deadline=None)
@given(joints)
@example(np.array([0.0, 0.0, 2.75, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))  # wrist in arm
@example(np.r_[REACH, REACH])  # arms through each other
@example(np.r_[7.5e-6, np.zeros(11)])  # near-parallel capsule axes
def test_coal_and_numpy_distances_agree(q):
    a, b = _numpy_arms(RELAY, q)
    expect = {(f"arm0/{x}", f"arm1/{y}"): d for (x, y), d in arms.arm_arm_distances(a, b).items()}
    for k, arm in enumerate((a, b)):
        for (x, y), d in arms.arm_self_distances(arm).items():
            expect[(f"arm{k}/{x}", f"arm{k}/{y}")] = d
    got = {(c.a, c.b): c for c in pair_clearances(WORLD, q, (PairKind.ARM_ARM, PairKind.ARM_SELF))}
    assert set(got) == set(expect)
    for key, c in got.items():
        d = expect[key]
        tol = _parallel_slack(a, b, key)
        if d > 1e-6:
            assert c.distance == pytest.approx(d, abs=tol), key
            assert np.linalg.norm(c.p_b - c.p_a) == pytest.approx(c.distance, abs=1e-9)
            np.testing.assert_allclose(c.normal, (c.p_b - c.p_a) / c.distance, atol=1e-6)
        elif {n.split("/")[1] for n in key} & BOX_PARTS:
            assert c.distance < 1e-6  # boxes meet: numpy reports 0, coal a depth
        else:
            assert c.distance == pytest.approx(d, abs=tol), key  # capsules: both signed


def test_arms_reaching_toward_each_other_collide_with_evidence():
    bad = violations(arm_arm(WORLD, np.r_[REACH, REACH]))
    assert bad
    first = bad[0]
    assert first.distance < 0 and first.a.startswith("arm0/") and first.b.startswith("arm1/")
    assert first.check.reason == "collision"
    assert 0.2 < first.p_a[0] < 0.85  # between the bases, where they meet
    assert "mm apart" in str(first)
    assert not violations(arm_arm(WORLD, np.r_[UPRIGHT, UPRIGHT]))


def test_arm_scene_collision_and_clearance():
    system = single()
    q = np.array(UPRIGHT)
    # a board 5 mm beside the elbow housing, then one through the forearm
    probe = SafetyWorld(system)
    probe.update(q)
    elbow = probe.data.oMi[3].translation
    clear = SafetyWorld(
        system, scene=[box("board", [0.05, 0.05, 0.05], make_T(p=elbow + np.array([0, 0, 0.3])))]
    )
    assert not violations(arm_scene(clear, q))
    hit = SafetyWorld(system, scene=[box("board", [0.05, 0.05, 0.05], make_T(p=elbow))])
    bad = violations(arm_scene(hit, q))
    assert bad and bad[0].b == "scene/board" and bad[0].a.startswith("arm0/forearm")
    near = SafetyWorld(
        system,
        scene=[sphere("ball", 0.02, make_T(p=elbow + np.array([0.0, 0.0, 0.066 + 0.02 + 0.005])))],
    )
    d = worst(arm_scene(near, q))
    assert d is not None and d.a == "arm0/forearm_elbow"
    assert d.distance == pytest.approx(0.005, abs=1e-9)  # 5 mm between the surfaces
    assert not d.ok  # below the 10 mm clearance


def test_base_is_not_checked_against_the_scene_it_stands_on():
    table = box("table", [2.0, 2.0, 0.05], make_T(p=[0, 0, -0.025]))
    w = SafetyWorld(single(), scene=[table])
    assert all(not c.a.endswith("/base") for c in arm_scene(w, UPRIGHT))
    assert not violations(arm_scene(w, UPRIGHT))


def test_self_collision_detected():
    w = SafetyWorld(single())
    q = np.array([0.0, -np.pi / 2, 2.9, 0.0, 0.0, 0.0])  # elbow folded, wrist into the upper arm
    bad = violations(arm_self(w, q))
    assert bad and bad[0].check.reason == "collision"


def test_mesh_scene_and_convex_keep_out(tmp_path):
    import open3d as o3d

    path = tmp_path / "cube.ply"
    cube = o3d.geometry.TriangleMesh.create_box(100, 100, 100).translate([-50, -50, -50])
    o3d.io.write_triangle_mesh(str(path), cube)
    v = Volume("cube", "mesh", make_T(p=[0.5, 0.5, 0.5]), (), path, 0.001)
    w = SafetyWorld(single(), scene=[v], keep_out=[v])
    assert len(w.parts_of(PartKind.SCENE)) == 1 and len(w.parts_of(PartKind.KEEP_OUT)) == 1
    # distances from the upright arm to the 10 cm cube at (0.5, 0.5, 0.5)
    c = worst(arm_scene(w, UPRIGHT))
    assert c is not None and c.distance > 0.1


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(name="x", shape="sphere", world_T_object=np.eye(4), dims=(-0.1,)),
        dict(name="x", shape="box", world_T_object=np.eye(4), dims=(0.1, 0.1)),
        dict(name="x", shape="cone", world_T_object=np.eye(4), dims=(0.1,)),
        dict(name="x", shape="sphere", world_T_object=np.full((4, 4), np.nan), dims=(0.1,)),
        dict(name="x", shape="sphere", world_T_object=np.eye(4), dims=(float("nan"),)),
        dict(name="x", shape="mesh", world_T_object=np.eye(4)),
    ],
)
def test_bad_volumes_are_input_errors(kwargs):
    with pytest.raises(InputError):
        Volume(**kwargs)


def test_bad_joint_vectors_are_rejected():
    with pytest.raises(InputError):
        WORLD.update(np.zeros(6))
    with pytest.raises(InputError):
        WORLD.update(np.full(12, np.nan))


@pytest.mark.parametrize("radius", [0.4, -0.4])
def test_a_curved_mirrors_plate_spans_its_face(radius: float) -> None:
    """The collision plate reaches from the face's highest point to ``thickness`` below its
    lowest (a concave rim stands proud of the vertex, a convex one falls behind it); a
    flat mirror's plate is [-thickness, 0] as before."""
    blocks = DEFAULT_MIRROR_BLOCKS
    flat = ur5e_robot("arm0")
    curved = replace(flat, mirror=replace(flat.mirror, surface=Sphere(radius)))
    half = np.hypot(*flat.mirror.size) / 2
    sag = radius - np.sign(radius) * np.sqrt(radius**2 - half**2)
    (_, fTp, ext), *_ = mirror_boxes(flat, blocks)
    (_, cTp, cext), *_ = mirror_boxes(curved, blocks)
    mTf = np.linalg.inv(flat.mirror.flange_T_mirror)
    top, bottom = (mTf @ cTp)[2, 3] + cext[2] / 2, (mTf @ cTp)[2, 3] - cext[2] / 2
    assert top == pytest.approx(max(sag, 0.0), abs=1e-15)
    assert bottom == pytest.approx(min(sag, 0.0) - blocks.thickness, abs=1e-15)
    assert (mTf @ fTp)[2, 3] == pytest.approx(-blocks.thickness / 2, abs=1e-15)
    assert ext[2] == blocks.thickness
