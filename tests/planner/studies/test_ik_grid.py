"""IK-grid study: the paper's Eq. 7 LM comparison row, the error map, the report."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.io.scenario import load_scenario, system_from_scenario
from planner.studies import ik_grid
from planner.studies.lm_ik import LMIK


@pytest.fixture(scope="module")
def system():  # type: ignore[no-untyped-def]
    return system_from_scenario(load_scenario(ik_grid.SCENARIO))


def test_lm_lands_on_a_target_of_the_home_beam_without_moving(system) -> None:  # type: ignore[no-untyped-def]
    tr = BeamModel(system).trace(system.home)
    target = tr.hits[-1] + 0.6 * tr.dirs[-1]
    r = LMIK(system).solve(target, system.home)
    assert r.solved and r.error < 1e-12
    assert np.allclose(r.q, system.home, atol=1e-9)


def test_lm_solves_a_displaced_target_to_machine_precision(system) -> None:  # type: ignore[no-untyped-def]
    tr = BeamModel(system).trace(system.home)
    target = tr.hits[-1] + 0.6 * tr.dirs[-1] + np.array([0.01, -0.01, 0.0])
    r = LMIK(system).solve(target, system.home)
    check = BeamModel(system).trace(r.q, target)  # independent of the LM's own figure
    assert r.solved and check.error < 1e-12 and r.error == pytest.approx(check.error, abs=1e-15)
    assert r.evaluations < 50 and r.time > 0


def test_eq7_lm_lands_the_hit_on_the_mirror_centre_where_the_closed_form_does(system) -> None:  # type: ignore[no-untyped-def]
    """A grid target the product's closed form solves (hit at the mirror centre): the LM
    with the h - c term reaches it with the hit at the centre; the spot-only LM reaches the
    spot too, but with the hit off centre (outside the ROI: what the term is for)."""
    from planner.ik import BeamIK
    from planner.io.scenario import targets_from_scenario
    from planner.plan.scenario_planner import ik_options
    from planner.studies.lm_ik import CENTRE_WEIGHT

    loaded = load_scenario(ik_grid.SCENARIO)
    target = targets_from_scenario(loaded, system).points[0]
    sol = BeamIK(system, ik_options(loaded.model.solver)).solve(target, None, system.home)
    assert sol.q is not None and sol.method == "closed_form"
    cf = BeamModel(system).trace(sol.q, target)
    assert np.max(np.abs(cf.uv)) < 1e-9  # the closed form's hit is the mirror centre
    r = LMIK(system, 1e-9, CENTRE_WEIGHT).solve(target, system.home)
    check = BeamModel(system).trace(r.q, target)  # independent of the LM's own figures
    M = BeamModel(system).world_T_mirrors(r.q)[0]
    assert r.solved and check.error < 1e-9
    assert np.linalg.norm(check.hits[0] - M[:3, 3]) < 1e-9 and r.centre_offset < 1e-9
    spot_only = LMIK(system, 1e-9).solve(target, system.home)
    assert spot_only.error < 1e-9 and spot_only.centre_offset > 0.01


def test_lm_joints_are_wrapped_by_whole_turns_into_the_limits() -> None:
    from planner.studies.lm_ik import wrap_joints

    lo, hi = np.array([-2 * np.pi, -np.pi]), np.array([2 * np.pi, np.pi])
    q = np.array([-6.34, 0.5 + 4 * np.pi])
    w = wrap_joints(q, np.zeros(2), lo, hi)
    assert np.allclose(w, [-6.34 + 2 * np.pi, 0.5])  # nearest the start, same angles
    assert np.allclose(np.cos(w), np.cos(q)) and np.allclose(np.sin(w), np.sin(q))
    # nearest the start is outside the limits: one more turn brings it in
    w = wrap_joints(np.array([6.0, 0.0]), np.array([-6.2, 0.0]), lo, hi)
    assert np.allclose(w, [6.0 - 2 * np.pi, 0.0]) and np.all(w >= lo)


@pytest.mark.slow
def test_study_compares_beamik_and_lm_and_draws_the_map(tmp_path: Path) -> None:
    text = ik_grid.SCENARIO.read_text().replace("n: [10, 10, 10]", "n: [2, 2, 2]")
    scenario = tmp_path / "small.yaml"
    scenario.write_text(text)
    fig = ik_grid.main(1, 0, tmp_path / "out", 1, None, scenario)
    rows = {m["method"]: m for m in fig["methods"]}
    assert set(rows) == {"BeamIK", ik_grid.LM_SPOT, ik_grid.LM_EQ7}
    assert rows["BeamIK"]["solved_pct"] == 100.0 and rows["BeamIK"]["error_max_mm"] < 1e-9
    for name in (ik_grid.LM_SPOT, ik_grid.LM_EQ7):
        lm = rows[name]
        assert 0.0 <= lm["solved_pct"] <= 100.0 and lm["time_mean_s"] > 0
    assert fig["targets"] == 8
    for f in ("report.md", "errors.png", "error_map.png", "methods.csv", "trials.csv"):
        assert (tmp_path / "out" / f).is_file()
    text = (tmp_path / "out" / "report.md").read_text()
    assert ik_grid.LM_SPOT in text and ik_grid.LM_EQ7 in text
