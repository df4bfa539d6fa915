"""Occlusion in planning: blocked beams fail as ``occluded`` with the segment, object and
point (checked against an analytic slab intersection), targets lying on a surface are not
blocked by it, n2_relay goes over its screen, paths get ``occluded`` gaps, the node checks."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from planner.ik import BeamIK, IKOptions
from planner.io.scenario import (
    SceneItem,
    load_scenario,
    scene_objects,
    system_from_scenario,
    targets_from_scenario,
)
from planner.model.scene import SceneModel
from planner.model.settings import TrajectorySettings
from planner.model.system import System, Targets
from planner.model.transforms import Array, make_T
from planner.plan.occlusion import check_points, occlusions, segment_labels
from planner.plan.scenario_planner import ik_options, plan_points, solve_path
from planner.plan.timed import time_solutions
from tests.paths import REPO
from tests.planner.ik import ik_systems as sy
from tests.planner.model.test_scene import box_entry

ROOT = REPO / "scenarios"
TARGET = np.array([0.3, 0.3, 0.3])


def box(name: str, centre: Array, extents: Array) -> SceneItem:
    return SceneItem(name, "box", make_T(p=centre), extents=np.asarray(extents, dtype=float))


def beam_clear_analytically(system: System, sol: object, items: list[SceneItem]) -> bool:
    """Every beam segment misses every box (slab method, 1 mm allowance at the end)."""
    pts = np.vstack([system.world_T_laser[:3, 3], sol.hits, sol.spot])  # type: ignore[attr-defined]
    for a, b in itertools.pairwise(pts):
        length = float(np.linalg.norm(b - a))
        for it in items:
            if box_entry(it.world_T_object, it.extents, a, (b - a) / length) < length - 1e-3:
                return False
    return True


def test_box_between_mirror_and_target_is_occluded_with_evidence() -> None:
    system = sy.n1()
    ik = BeamIK(system)
    free = plan_points(system, Targets(TARGET[None]), IKOptions())
    h = free[0].hits[0]
    item = box("crate", (h + TARGET) / 2, [0.05, 0.05, 0.05])
    scene = SceneModel([item])
    [sol] = check_points(ik, scene, Targets(TARGET[None]), free, shifts=())  # home only
    assert (sol.status, sol.reason, sol.q) == ("failed", "occluded", None)
    ev = sol.evidence["occluded"]
    assert (ev["segment"], ev["object"]) == ("arm0->target", "crate")
    v = (TARGET - h) / np.linalg.norm(TARGET - h)
    t_ref = box_entry(item.world_T_object, item.extents, h, v)
    assert ev["distance_m"] == pytest.approx(t_ref, abs=1e-6)
    assert np.allclose(ev["point"], h + t_ref * v, atol=1e-6)
    assert ev["segment_length_m"] == pytest.approx(np.linalg.norm(TARGET - h), abs=1e-12)
    assert np.allclose(ev["q"], free[0].q)
    # a box on the laser -> mirror segment is reported there
    laser = system.world_T_laser[:3, 3]
    blocked = occlusions(system, SceneModel([box("post", (laser + h) / 2, [0.02] * 3)]), free)
    assert blocked[0]["segment"] == "laser->arm0"


def test_plan_points_retries_other_members_or_fails() -> None:
    """A small box in the way of the first member: the retry finds a clear one (verified by
    the slab method); a wall across every approach: occluded, the other targets unaffected."""
    system = sy.n1()
    pts = np.array([TARGET, TARGET + np.array([0.02, 0.0, 0.0]), [0.3, 0.1, 0.3]])
    free = plan_points(system, Targets(pts), IKOptions())
    h = free[0].hits[0]
    small = box("crate", 0.5 * (h + TARGET), [0.03] * 3)
    assert not beam_clear_analytically(system, free[0], [small])
    sols = plan_points(system, Targets(pts[:1]), IKOptions(), scene=SceneModel([small]))
    assert sols[0].ok and sols[0].evidence["occlusion_retry"] >= 1
    assert beam_clear_analytically(system, sols[0], [small])
    # a 0.1 m block around the first two targets: nothing reaches them, the third is outside
    shell = box("block", TARGET + np.array([0.01, 0.0, 0.0]), [0.1, 0.1, 0.1])
    sols = plan_points(system, Targets(pts), IKOptions(), scene=SceneModel([shell]))
    assert [s.reason for s in sols[:2]] == ["occluded", "occluded"]
    assert sols[0].evidence["occluded"]["retries"] == 7
    assert sols[2].ok and sols[2].error < 1e-9


def test_target_on_a_board_is_not_occluded_by_it() -> None:
    system = sy.n1()
    target = np.array([0.3, 0.3, 0.0])
    board = box("board", target - [0, 0, 0.005], [0.3, 0.3, 0.01])  # top face through target
    scene = SceneModel([board])
    sols = plan_points(system, Targets(target[None], np.array([[0.0, 0.0, 1.0]])), IKOptions(),
                       scene=scene)  # fmt: skip
    assert sols[0].ok and "occlusion_retry" not in sols[0].evidence
    # the board is there: with no end allowance the last segment meets it at the spot
    h, spot = sols[0].hits[-1], sols[0].spot
    d = scene.segment_hits(h, spot, end_margin=0.0)
    assert d == pytest.approx(np.linalg.norm(spot - h), abs=1e-6)
    assert scene.segment_hits(h, spot - 0.01 * (spot - h)) is None


@pytest.fixture(scope="module")
def n2() -> tuple[System, Targets, list[SceneItem], IKOptions]:
    scn = load_scenario(ROOT / "n2_relay.yaml")
    system = system_from_scenario(scn)
    return (
        system,
        targets_from_scenario(scn, system),
        scene_objects(scn),
        ik_options(scn.model.solver),
    )


def test_n2_relay_goes_over_the_screen(
    n2: tuple[System, Targets, list[SceneItem], IKOptions],
) -> None:
    system, targets, items, options = n2
    sols = plan_points(system, targets, options, scene=SceneModel(items))
    assert len(sols) == 32 and all(s.ok for s in sols)
    for k, s in enumerate(sols):
        assert beam_clear_analytically(system, s, items)
        # arm0's mirror could not reach the target directly: the screen is in the way
        h0 = s.hits[0]
        v = targets.points[k] - h0
        length = float(np.linalg.norm(v))
        assert box_entry(items[0].world_T_object, items[0].extents, h0, v / length) < length


def test_n2_relay_with_the_beam_from_mirror_1_blocked(
    n2: tuple[System, Targets, list[SceneItem], IKOptions],
) -> None:
    system, targets, items, options = n2
    # a roof over the grid (x from the screen to arm1, z = 0.12), under arm1's mirror
    roof = box("roof", [-1.035, 0.30, 0.12], [0.53, 1.2, 0.01])
    sols = plan_points(system, targets, options, scene=SceneModel([*items, roof]))
    assert [s.reason for s in sols] == ["occluded"] * 32
    for k, s in enumerate(sols):
        ev = s.evidence["occluded"]
        assert (ev["segment"], ev["object"]) == ("arm1->target", "roof")
        assert ev["point"][2] == pytest.approx(0.125, abs=1e-6)  # roof top face
        assert ev["distance_m"] < ev["segment_length_m"]
        a, b, p = (np.asarray(ev[key]) for key in ("start", "end", "point"))
        assert np.allclose(b, targets.points[k], atol=1e-9)  # the spot, on the target
        assert np.allclose(p, a + ev["distance_m"] * (b - a) / np.linalg.norm(b - a), atol=1e-12)
        sol_free = plan_points(system, Targets(targets.points[k : k + 1]), options, ev["q"])
        assert np.allclose(sol_free[0].hits[-1], a, atol=1e-6)  # the blocked beam, re-traced
    assert segment_labels(system) == ["laser->arm0", "arm0->arm1", "arm1->target"]


def test_curve_path_on_its_board_and_with_a_post() -> None:
    scn = load_scenario(ROOT / "curve_path.yaml")
    system = system_from_scenario(scn)
    targets = targets_from_scenario(scn, system)
    options, items = ik_options(scn.model.solver), scene_objects(scn)
    sols, path = solve_path(system, targets, options, scene=SceneModel(items))
    assert path.gaps == () and all(s.ok for s in sols)
    # a thin post halfway between the mirror and samples 70..90 hides a stretch of the path
    k_mid = 80
    mid = 0.5 * (sols[k_mid].hits[-1] + targets.points[k_mid])
    post = box("post", mid, [0.01, 0.01, 0.02])
    sols2, path2 = solve_path(system, targets, options, scene=SceneModel([*items, post]))
    bad = [k for k, s in enumerate(sols2) if not s.ok]
    assert bad and bad == list(range(bad[0], bad[-1] + 1)) and bad[0] < k_mid <= bad[-1]
    assert {sols2[k].reason for k in bad} == {"occluded"}
    assert all(sols2[k].evidence["occluded"]["object"] == "post" for k in bad)
    # exactly the samples whose solved beam crosses the post (slab method)
    crossing = [k for k, s in enumerate(sols) if not beam_clear_analytically(system, s, [post])]
    assert crossing == bad
    [gap] = path2.gaps
    assert (gap.k0, gap.k1, gap.reason) == (bad[0], bad[-1] + 1, "occluded")
    assert "post" in gap.detail
    assert [(s.k0, s.k1) for s in path2.segments] == [(0, bad[0]), (bad[-1] + 1, len(targets))]
    assert np.isnan(path2.q[bad]).all() and not path2.ok[bad].any()
    timed = time_solutions(system, targets, sols2, TrajectorySettings(rate=100.0), path=path2)
    assert timed is not None
    assert [s.kind for s in timed.trajectory.segments].count("path") == 2


def test_node_plan_reports_occluded(tmp_path: Path) -> None:
    from planner.bus.session import encode
    from planner.service.client import make_request
    from planner.service.handler import handler_from_scenario

    text = (ROOT / "n2_relay.yaml").read_text()
    # a roof over the targets, clear of arm1 (whose base stands at x = -1.2)
    roof = "  - name: roof\n    box: [0.23, 0.4, 0.01]\n    world_T_object: {xyz: [-0.885, 0.3, 0.12]}\n"
    text = text.replace("targets:\n", roof + "targets:\n", 1)
    (tmp_path / "n2_roof.yaml").write_text(text)
    handler = handler_from_scenario(tmp_path / "n2_roof.yaml")
    doc = handler.plan(handler.parse(encode(make_request([[-0.88, 0.30, 0.05]])))).to_document()
    [sol] = doc["solutions"]
    assert (sol["status"], sol["reason"], "q" in sol) == ("failed", "occluded", False)
    extra = doc["metrics"]["extra"]
    assert extra["failed_occluded"] == 1 and set(extra) == {
        "failed_occluded",
        "surface_distance_max",
    }


def test_node_plan_applies_the_keep_out_rules(tmp_path: Path) -> None:
    """The running planner node plans under the same safety rules as ``beamrelay plan``."""
    from planner.bus.session import encode
    from planner.service.client import make_request
    from planner.service.handler import handler_from_scenario

    text = (ROOT / "n2_relay.yaml").read_text()
    text += "keep_out:\n  - {name: eye, sphere: 0.01, world_T_object: {xyz: [-0.88, 0.3, 0.05]}}\n"
    (tmp_path / "n2_eye.yaml").write_text(text)
    handler = handler_from_scenario(tmp_path / "n2_eye.yaml")
    doc = handler.plan(
        handler.parse(encode(make_request([[-0.88, 0.30, 0.05], [-0.86, 0.28, 0.05]])))
    ).to_document()
    first, second = doc["solutions"]
    assert (first["status"], first["reason"]) == ("failed", "keep_out")  # inside the eye
    assert second["status"] == "ok"  # 28 mm away: a beam that misses the eye is found
    from planner.verify.check import check_plan

    results = {r.name: r for r in check_plan(doc)}
    assert not results["safety"].findings
