"""The path NLP with the clearance as constraints: a keep-out ball beside the curve path's
beams, which the plain path NLP's beams cross at a stretch of samples, is kept clear by the
constrained re-solve (no gap, every sample on target, every beam clear of the ball by the
checker's independent numpy geometry)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
from planner.model.transforms import make_T
from planner.plan.scenario_planner import ik_options, solve_path
from planner.safety import sphere
from planner.safety.model import Safety
from tests.paths import REPO
from tests.planner.safety.numpy_rules import hits, setup


@pytest.fixture(scope="module")
def curve():  # type: ignore[no-untyped-def]
    scn = load_scenario(REPO / "scenarios" / "curve_path.yaml")
    system = system_from_scenario(scn)
    return scn, system, targets_from_scenario(scn, system)


@pytest.mark.slow
def test_path_beams_keep_clear_of_a_keep_out_ball(curve) -> None:  # type: ignore[no-untyped-def]
    from planner.ik import BeamIK

    scn, system, targets = curve
    k = len(targets) // 2
    options = ik_options(scn.model.solver)
    sol = BeamIK(system, options).solve(targets.points[k], targets.normal(k))
    assert sol.hits is not None
    centre = (sol.hits[0] + targets.points[k]) / 2  # on that sample's last beam segment
    eye = sphere("eye", 0.005, make_T(p=centre))
    sols, path = solve_path(system, targets, options, safety=Safety(system, (), (eye,)))
    assert path.complete and all(s.ok for s in sols)
    # the plain NLP result broke the rule at a stretch of samples: re-solved with the
    # clearance to none, or replaced by the (safe) per-sample warm start; either way every
    # beam is checked below
    status = " ".join(seg.status for seg in path.segments)
    m = re.search(r"\+clearance \(\w+; unsafe samples (\d+) -> (\d+)\)", status)
    resolved = m is not None and int(m.group(1)) >= 10 and int(m.group(2)) == 0
    assert resolved or "warm_start (NLP result unsafe" in status, status
    assert float(np.nanmax(path.error)) <= 1e-9
    s = setup(system, keep=(eye,))
    for sol in sols:
        assert sol.hits is not None and sol.spot is not None
        beam = np.vstack([system.world_T_laser[:3, 3], sol.hits, sol.spot])
        assert hits(s, system, sol.q, beam) == []  # type: ignore[arg-type]
