"""The IPOPT steps of the IK with the clearance as constraints: where the plain NLP's
optimum breaks a distance rule (the beam through a keep-out volume, an arm within the
clearance of a scene object) the constrained NLP returns a configuration that keeps it,
re-checked with the checker's independent numpy geometry; where no configuration can, the
target fails with the rule's reason and evidence."""

from __future__ import annotations

import numpy as np
import pytest

from planner.ik import BeamIK, IKOptions, Solution
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.system import System
from planner.model.transforms import look_at, make_T
from planner.safety import box, sphere
from planner.safety.model import Safety, SafetySettings
from planner.safety.shapes import Volume
from planner.verify.safety_shapes import arm_shapes
from tests.paths import REPO
from tests.planner.safety.numpy_rules import hits, setup

OPTIMAL = IKOptions(max_incidence=np.radians(80), optimal=True)
TARGET = np.array([-0.492, -0.519, 0.0])  # the paper grid's centre


@pytest.fixture(scope="module")
def paper() -> System:
    return system_from_scenario(load_scenario(REPO / "scenarios" / "paper_n1.yaml"))


@pytest.fixture(scope="module")
def optimum(paper: System) -> Solution:
    sol = BeamIK(paper, OPTIMAL).solve(TARGET)
    assert sol.ok and sol.method == "closed_form+ipopt"
    return sol


def _beam(system: System, sol: Solution) -> np.ndarray:
    assert sol.hits is not None and sol.spot is not None
    return np.vstack([system.world_T_laser[:3, 3], sol.hits, sol.spot])


def _broken(system: System, sol: Solution, scene: tuple[Volume, ...] = (),
            keep: tuple[Volume, ...] = (), clearance: float = 0.01) -> set[str]:  # fmt: skip
    assert sol.q is not None
    s = setup(system, scene, keep, clearance)
    return {h.check for h in hits(s, system, sol.q, _beam(system, sol))}


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return float(np.linalg.norm(a + t * (b - a) - p))


def _post_near_forearm(system: System, q: np.ndarray, gap: float) -> Volume:
    """A 30 mm ball ``gap`` m from the forearm capsule at ``q`` (beside its middle)."""
    shapes = arm_shapes(np.eye(4), q[None], system.robots[0].mirror.flange_T_mirror,
                        np.array([0.075, 0.075]))  # fmt: skip
    c = next(s for s in shapes if s.name == "forearm")
    a, b, r = c.A[0], c.B[0], float(np.ravel(c.r)[0])
    side = np.cross(b - a, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    return sphere("post", 0.03, make_T(p=(a + b) / 2 + (r + 0.03 + gap) * side))


def test_optimal_step_keeps_the_beam_out_of_a_keep_out_volume(
    paper: System, optimum: Solution
) -> None:
    assert optimum.hits is not None
    centre = (optimum.hits[0] + TARGET) / 2  # on the optimum's last segment
    eye = (sphere("eye", 0.01, make_T(p=centre)),)
    assert "beam_keep_out" in _broken(paper, optimum, keep=eye)
    on = BeamIK(paper, OPTIMAL, Safety(paper, (), eye)).solve(TARGET)
    # the IPOPT result is kept (not discarded for the closed-form member) and is safe
    assert on.ok and on.method == "closed_form+ipopt" and on.error <= 1e-9
    assert _broken(paper, on, keep=eye) == set()
    assert on.hits is not None
    assert _segment_distance(centre, on.hits[0], TARGET) >= 0.01  # outside the sphere


def test_optimal_step_keeps_the_arm_scene_clearance(paper: System, optimum: Solution) -> None:
    assert optimum.q is not None
    post = (_post_near_forearm(paper, optimum.q, 0.004),)
    assert _broken(paper, optimum, scene=post) == {"arm_scene"}  # 4 mm < 10 mm
    on = BeamIK(paper, OPTIMAL, Safety(paper, post)).solve(TARGET)
    assert on.ok and on.method == "closed_form+ipopt" and on.error <= 1e-9
    assert _broken(paper, on, scene=post, clearance=0.01) == set()  # >= 10 mm by numpy
    assert on.q is not None and np.abs(on.q - optimum.q).max() < 0.2  # a nearby optimum


def test_multistart_without_a_closed_form_meets_the_clearance(
    paper: System, optimum: Solution
) -> None:
    """An arm with no closed form (a URDF): the NLP is the only solver; one start (home)."""
    assert optimum.q is not None
    post = (_post_near_forearm(paper, optimum.q, 0.004),)
    one = IKOptions(max_incidence=np.radians(80), optimal=True, starts=0)
    plain = BeamIK(paper, one)
    plain.closed_form = None
    first = plain.solve(TARGET)
    assert first.ok and first.method == "multistart"
    assert "arm_scene" in _broken(paper, first, scene=post)
    ik = BeamIK(paper, one, Safety(paper, post))
    ik.closed_form = None
    on = ik.solve(TARGET)
    assert on.ok and on.method == "multistart" and on.error <= 1e-9
    assert _broken(paper, on, scene=post) == set()


def test_multistart_fails_with_evidence_when_no_configuration_is_clear(paper: System) -> None:
    laser, v0 = paper.world_T_laser[:3, 3], paper.world_T_laser[:3, 2]
    sleeve = (box("sleeve", [0.25, 0.25, 2.0], look_at(laser + 0.9 * v0, laser + 2 * v0)),)
    ik = BeamIK(paper, OPTIMAL, Safety(paper, sleeve, settings=SafetySettings(clearance=0.01)))
    ik.closed_form = None
    sol = ik.solve(TARGET)
    assert not sol.ok and sol.q is None and sol.reason == "collision"
    ev = sol.evidence["nlp"]
    assert isinstance(ev, dict) and ev["check"] == "arm_scene" and ev["b"] == "scene/sleeve"
    assert str(ev["a"]).startswith("arm0/")
    assert float(ev["distance_m"]) < float(ev["required_m"]) == 0.01
    assert len(ev["point"]) == 3
