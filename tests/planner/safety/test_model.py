"""The planner's safety rules (Safety: security-margin collision calls, beam segments batched
in a second geometry model) against pair-by-pair coal distances and against the checker's
independent numpy geometry, on random configurations and beams."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.model.transforms import make_T
from planner.safety import (
    SafetyWorld,
    all_pair_distances,
    beam_arm,
    beam_keep_out,
    box,
    sphere,
)
from planner.safety.geometry import PairKind
from planner.safety.model import Safety, SafetySettings
from tests.planner.safety.numpy_rules import hits, setup
from tests.planner.safety.worlds import UPRIGHT, relay

KEEP = (sphere("eye", 0.05, make_T(p=[0.5, -0.3, 0.5])), box("slab", [0.2, 0.3, 0.02],
                                                               make_T(p=[0.4, 0.3, 0.3])))  # fmt: skip
SCENE = (box("table", [3.0, 3.0, 0.04], make_T(p=[0.5, 0.0, -0.03])),)


@pytest.fixture(scope="module")
def rules() -> Safety:
    return Safety(relay(), SCENE, KEEP, SafetySettings(clearance=0.02))


def _configs(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.r_[UPRIGHT, UPRIGHT][None] + rng.uniform(-1.2, 1.2, (n, 12))


def test_arm_rule_matches_every_pair_distance(rules: Safety) -> None:
    world = rules.world
    req = np.array([rules.required(k) for k in world.pair_kinds])
    flagged = 0
    for q in _configs(150, 1):
        d = all_pair_distances(world, q)
        bad = rules.arms(q)
        assert (bad is None) == bool(np.all(d >= req))
        if bad is not None:
            flagged += 1
            assert bad.margin == pytest.approx(float(np.min(d - req)), abs=1e-9)
            assert bad.reason == "collision"
    assert 20 < flagged < 150


def test_beam_rule_matches_pair_by_pair_distances(rules: Safety) -> None:
    world, rng = rules.world, np.random.default_rng(2)
    n = 0
    for q in _configs(120, 3):
        P = rng.uniform([-0.3, -1.0, 0.0], [1.3, 1.0, 1.2], (4, 3))
        ref = beam_arm(world, q, P, 0.02) + beam_keep_out(world, P)
        worst = min((c.distance - c.required for c in ref), default=np.inf)
        bad = rules.beam(q, P, apertures=False)
        if worst < 0:
            n += 1
            assert bad is not None and bad.margin == pytest.approx(worst, abs=1e-9)
            assert bad.reason in ("occluded", "keep_out")
        else:
            assert bad is None
    assert n > 20


def test_planner_and_checker_geometry_agree(rules: Safety) -> None:
    """Violations found by coal and by the checker's own numpy geometry agree, up to
    configurations within 1 mm of a bound (coal's and numpy's shapes are the same)."""
    system = rules.system
    s = setup(system, SCENE, KEEP, clearance=0.02)
    world, rng = rules.world, np.random.default_rng(4)
    agree = 0
    for q in _configs(60, 5):
        P = rng.uniform([-0.3, -1.0, 0.0], [1.3, 1.0, 1.2], (4, 3))
        ours = [v for v in (rules.arms(q), rules.beam(q, P, apertures=False)) if v]
        theirs = {h.reason for h in hits(s, system, q, P)}
        near = min(
            np.min(
                np.abs(all_pair_distances(world, q) - [rules.required(k) for k in world.pair_kinds])
            ),
            min(abs(c.distance - c.required) for c in beam_arm(world, q, P, 0.02)),
        )
        if near > 1e-3:
            assert bool(ours) == bool(theirs) and {v.reason for v in ours} <= theirs
            agree += 1
    assert agree > 40


def test_segments_touching_their_mirror_only_avoid_that_robot(rules: Safety) -> None:
    """A segment 5 mm beside arm0's mount breaks the 20 mm clearance, unless it is one that
    leaves or reaches arm0's mirror: then it must only not touch arm0's parts."""
    world, pairs = rules.world, rules.beam_pairs
    q = np.r_[UPRIGHT, UPRIGHT]
    world.update(q)
    mount = next(p for p in world.parts if p.name == "arm0/mount")
    M = world.placement(mount.index)
    R, centre = M.getRotation(), M.getTranslation()
    beside = centre + R[:, 0] * (world.geometry(mount.index).halfSide[0] + 0.005)
    a, b = beside + 0.01 * R[:, 1], beside - 0.01 * R[:, 1]
    far = np.array([5.0, 5.0, 5.0])

    def flagged(P: np.ndarray) -> set[tuple[int, str]]:
        pairs.place(P)
        return {(c.segment, c.b) for c in pairs.violations()}

    # segment 2 (arm1 -> target) touches no mirror of arm0: the clearance applies
    assert (2, "arm0/mount") in flagged(np.array([far, far + 1, a, b]))
    # segments 0 (laser -> arm0) and 1 (arm0 -> arm1) touch arm0's mirror: only no contact
    assert (0, "arm0/mount") not in flagged(np.array([a, b, far, far + 1]))
    assert (1, "arm0/mount") not in flagged(np.array([far, a, b, far + 1]))


def test_kinds_of_required_distance(rules: Safety) -> None:
    assert rules.required(PairKind.ARM_SELF) == 0.0
    assert rules.required(PairKind.ARM_ARM) == rules.required(PairKind.ARM_SCENE) == 0.02


def test_robot_without_collision_geometry_is_reported(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from planner.model.kinematics import RobotKinematics
    from planner.model.system import Limits, Mirror, Robot, System
    from planner.model.transforms import look_at

    urdf = tmp_path / "arm.urdf"
    text = Path(RobotKinematics.ur5e().source).read_text()
    assert 'xyz="0.0 0 0.1625"' in text
    urdf.write_text(text.replace('xyz="0.0 0 0.1625"', 'xyz="0.0 0 0.3"'))  # a taller arm
    kin = RobotKinematics.from_urdf(urdf)
    robot = Robot("odd", kin, np.eye(4), Mirror(make_T(p=[0, 0, 0.03])), np.zeros(6),
                  Limits.ur_default())  # fmt: skip
    system = System(look_at([0.6, -0.4, 0.3], [0.0, -0.4, 0.3]), (robot,))
    with pytest.raises(Exception, match="no collision capsules"):
        SafetyWorld(system)
    world = SafetyWorld(system, bare=True)
    assert world.unchecked == ["odd"] and [p.name for p in world.parts] == [
        "odd/mirror",
        "odd/mount",
    ]
