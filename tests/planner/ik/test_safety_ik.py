"""The IK under the safety rules: each failure constructed on the paper's N = 1 layout (and
the shipped two-arm scenario), avoided when another family member is safe, failing with
the right reason and evidence when none is. Solutions are re-checked with the checker's
independent numpy geometry."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.trace import mirror_poses
from planner.ik import BeamIK, IKOptions, Solution
from planner.ik.safe_members import BUDGET
from planner.ik.solve import CLEARANCE_BUDGET
from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
from planner.model.system import System
from planner.model.transforms import look_at, make_T
from planner.safety import box, sphere
from planner.safety.model import Safety, SafetySettings
from planner.safety.shapes import Volume
from planner.verify.safety_shapes import arm_shapes
from tests.paths import REPO
from tests.planner.safety.numpy_rules import hits, setup

OPTS = IKOptions(max_incidence=np.radians(80))
TARGET = np.array([-0.492, -0.519, 0.0])  # the paper grid's centre


@pytest.fixture(scope="module")
def paper() -> System:
    scn = load_scenario(REPO / "scenarios" / "paper_n1.yaml")
    return system_from_scenario(scn)


def _beam(system: System, sol: Solution) -> np.ndarray:
    assert sol.hits is not None and sol.spot is not None
    return np.vstack([system.world_T_laser[:3, 3], sol.hits, sol.spot])


def _solve(system: System, target: np.ndarray, scene: tuple[Volume, ...] = (),
           keep: tuple[Volume, ...] = (), **kw: float) -> tuple[Solution, Solution]:  # fmt: skip
    """(without, with) the safety rules."""
    rules = Safety(system, scene, keep, SafetySettings(**kw))
    return BeamIK(system, OPTS).solve(target), BeamIK(system, OPTS, rules).solve(target)


def _checks(system: System, sol: Solution, scene: tuple[Volume, ...] = (),
            keep: tuple[Volume, ...] = (), target: np.ndarray | None = None,
            clearance: float = 0.01) -> set[str]:  # fmt: skip
    assert sol.q is not None
    s = setup(system, scene, keep, clearance)
    return {h.check for h in hits(s, system, sol.q, _beam(system, sol), target)}


def test_beam_into_keep_out_is_avoided_by_another_member(paper: System) -> None:
    first = BeamIK(paper, OPTS).solve(TARGET)
    eye = (sphere("eye", 0.01, make_T(p=(first.hits[0] + TARGET) / 2)),)  # type: ignore[index]
    off, on = _solve(paper, TARGET, keep=eye)
    assert "beam_keep_out" in _checks(paper, off, keep=eye)
    assert on.ok and on.evidence["safety_rejected"] >= 1
    assert _checks(paper, on, keep=eye) == set()
    assert on.error <= 1e-9  # still on the target


def test_beam_into_keep_out_fails_when_every_beam_crosses_it(paper: System) -> None:
    first = BeamIK(paper, OPTS).solve(TARGET)
    towards = (first.hits[0] - TARGET) / np.linalg.norm(first.hits[0] - TARGET)  # type: ignore[index]
    eye = (sphere("eye", 0.05, make_T(p=TARGET + 0.055 * towards)),)  # covers every approach
    _, on = _solve(paper, TARGET, keep=eye)
    assert not on.ok and on.reason == "keep_out" and on.q is None
    ev = on.evidence
    assert ev["check"] == "beam_keep_out" and ev["b"] == "keep_out/eye"
    assert ev["a"] == "beam arm0->target" and float(ev["distance_m"]) < 0  # type: ignore[arg-type]
    assert int(ev["members_unsafe"]) > 10  # type: ignore[call-overload]


def test_target_inside_keep_out_fails_at_once_with_its_depth(paper: System) -> None:
    centre = TARGET + np.array([0.005, 0.0, 0.0])
    eye = (sphere("eye", 0.02, make_T(p=centre)),)
    _, on = _solve(paper, TARGET, keep=eye)
    assert on.reason == "keep_out" and on.evidence["check"] == "target_keep_out"
    assert on.evidence["distance_m"] == pytest.approx(-0.015, abs=1e-9)  # 20 mm - 5 mm
    assert on.iterations == 0  # no member was searched


def test_retro_reflection_into_the_laser_fails_on_axis(paper: System) -> None:
    laser, v0 = paper.world_T_laser[:3, 3], paper.world_T_laser[:3, 2]
    off, on = _solve(paper, laser - 0.3 * v0)  # behind the laser: only normal incidence
    assert off.ok and "laser_return" in _checks(paper, off)
    assert on.reason == "keep_out" and on.evidence["check"] == "laser_return"
    assert on.evidence["b"] == "laser aperture"
    assert float(on.evidence["distance_m"]) < 1e-6  # type: ignore[arg-type]


def test_retro_reflection_is_avoided_off_axis(paper: System) -> None:
    laser, v0 = paper.world_T_laser[:3, 3], paper.world_T_laser[:3, 2]
    side = np.cross(v0, [1.0, 0.0, 0.0])
    target = laser - 0.4 * v0 + 0.016 * side / np.linalg.norm(side)
    off, on = _solve(paper, target)
    assert "laser_return" in _checks(paper, off)  # the nearest member returns within 10 mm
    assert on.ok and _checks(paper, on) == set()
    # the chosen beam passes the laser exit more than 10 mm away
    beam = _beam(paper, on)
    d = np.linalg.norm(np.cross(beam[2] - beam[1], laser - beam[1])) / np.linalg.norm(
        beam[2] - beam[1]
    )
    assert d > 0.01


@pytest.mark.parametrize("link", ["upper_arm", "forearm"])
def test_beam_through_the_own_arm_is_avoided(paper: System, link: str) -> None:
    shapes = arm_shapes(np.eye(4), paper.home[None], paper.robots[0].mirror.flange_T_mirror,
                        (0.075, 0.075))  # fmt: skip
    c = next(s for s in shapes if s.name == link)
    mirror = mirror_poses(paper, paper.home)[0][:3, 3]
    target = mirror + 1.6 * ((c.A + c.B)[0] / 2 - mirror)  # behind the link from the mirror
    off, on = _solve(paper, target)
    assert "beam_arm" in _checks(paper, off)
    assert on.ok and _checks(paper, on) == set()


def test_beam_into_the_own_base_fails_as_occluded(paper: System) -> None:
    _, on = _solve(paper, np.array([0.0, 0.0, 0.02]))  # inside the base housing
    assert on.reason == "occluded" and on.evidence["check"] == "beam_arm"
    assert on.evidence["b"] == "arm0/base"
    by_reason = on.evidence["unsafe_by_reason"]
    assert max(by_reason, key=by_reason.get) == "occluded"  # type: ignore[arg-type]


def test_arm_scene_collision_is_avoided(paper: System) -> None:
    shapes = arm_shapes(np.eye(4), paper.home[None], paper.robots[0].mirror.flange_T_mirror,
                        (0.075, 0.075))  # fmt: skip
    elbow = next(s for s in shapes if s.name == "upper_arm_elbow")
    post = (box("post", [0.05, 0.05, 0.05], make_T(p=(elbow.A + elbow.B)[0] / 2 + [0, 0, 0.09])),)
    off, on = _solve(paper, TARGET, scene=post)
    assert "arm_scene" in _checks(paper, off, scene=post)
    assert on.ok and _checks(paper, on, scene=post) == set()


def test_arm_scene_collision_fails_when_the_mirror_must_be_inside(paper: System) -> None:
    laser, v0 = paper.world_T_laser[:3, 3], paper.world_T_laser[:3, 2]
    sleeve = (box("sleeve", [0.25, 0.25, 2.0], look_at(laser + 0.9 * v0, laser + 2 * v0)),)
    _, on = _solve(paper, TARGET, scene=sleeve)
    assert on.reason == "collision" and on.evidence["check"] == "arm_scene"
    assert on.evidence["b"] == "scene/sleeve" and str(on.evidence["a"]).startswith("arm0/")
    assert len(on.evidence["point"]) == 3  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def shared() -> tuple[System, np.ndarray, Safety]:
    scn = load_scenario(REPO / "scenarios" / "n2_shared.yaml")
    system = system_from_scenario(scn)
    return system, targets_from_scenario(scn, system).points, Safety.from_scenario(scn, system)


def test_arm_arm_clearance_is_kept_in_the_shared_space(shared) -> None:  # type: ignore[no-untyped-def]
    system, points, rules = shared
    assert rules.settings.clearance == 0.02
    off, on = BeamIK(system, OPTS), BeamIK(system, OPTS, rules)
    s = setup(system, clearance=0.02)
    close, q_off, q_on = 0, system.home, system.home
    for p in points:
        a, b = off.solve(p, None, q_off), on.solve(p, None, q_on)
        q_off, q_on = a.q, b.q
        close += any(h.check == "arm_arm" for h in hits(s, system, a.q))  # type: ignore[arg-type]
        assert b.ok and hits(s, system, b.q, _beam(system, b)) == []  # type: ignore[arg-type]
    assert close >= 5  # without the rules the arms come closer than 20 mm


def test_arm_arm_collision_fails_with_both_arms_named(shared) -> None:  # type: ignore[no-untyped-def]
    system, points, _ = shared
    # the bases' housings are 0.64 - 2 x 0.076 = 0.488 m apart at every configuration
    rules = Safety(system, settings=SafetySettings(clearance=0.5))
    ik = BeamIK(system, OPTS, rules)
    nlp_solves = 0
    inner = ik.nlp.solve

    def counted(*args, **kw):  # type: ignore[no-untyped-def]
        nonlocal nlp_solves
        nlp_solves += 1
        return inner(*args, **kw)

    ik.nlp.solve = counted  # type: ignore[method-assign]
    sol = ik.solve(points[0])
    assert sol.reason == "collision" and sol.evidence["check"] == "arm_arm"
    a, b = str(sol.evidence["a"]), str(sol.evidence["b"])
    assert {a.split("/")[0], b.split("/")[0]} == {"arm0", "arm1"}
    assert float(sol.evidence["distance_m"]) <= 0.488 + 1e-9  # type: ignore[arg-type]
    assert sol.evidence["unsafe_by_reason"] == {"collision": sol.evidence["members_unsafe"]}
    # the work is bounded: the closed-form search gives up after its budget of rejections,
    # then one NLP per multi-start seed (previous joints, home, the random starts) plus at
    # most the clearance-cut budget of re-solves
    assert sol.evidence["members_unsafe"] == BUDGET
    assert 0 < nlp_solves <= 2 + OPTS.starts + CLEARANCE_BUDGET
