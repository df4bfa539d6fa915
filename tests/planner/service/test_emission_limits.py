"""The plan-side check of ``laser.limits`` (:mod:`planner.service.emission`) and its place
in execution: a trajectory that would pass a limit is never sent."""

from __future__ import annotations

from typing import Any

import pytest

from planner.io.plan import Verdict
from planner.service.emission import emission_excess
from planner.service.stream import Execution
from schemas.scenario import LaserLimits
from tests.planner.service.plans import as_plan

LASER = {"power": 0.05, "limits": {"max_on": 2.0, "max_spot_energy": 0.05,
                                   "max_session_energy": 0.12}}  # fmt: skip


@pytest.mark.parametrize(
    "spans, text",
    [([[0.0, 0.9]], None),  # 0.045 J, 0.9 s
     ([[0.0, 1.2]], "t = 0.000 s delivers 0.06 J (1.200 s at 0.05 W), over laser.limits.max_spot_energy 0.05 J"),
     ([[0.0, 0.9], [1.5, 2.4], [3.0, 3.9]], "delivers 0.135 J, over laser.limits.max_session_energy 0.12 J"),
     ([[0.0, 0.6], [0.7, 1.3]], "from t = 0.000 s delivers 0.06 J (1.200 s"),  # one exposure
     ([[1.0, 1.5], [2.0, 4.5]], "from t = 2.000 s lasts 2.500 s, over laser.limits.max_on 2 s")],
)  # fmt: skip
def test_intervals_are_checked_against_each_limit(
    spans: list[list[float]], text: str | None
) -> None:
    laser: dict[str, Any] = dict(LASER)
    if "max_on" in (text or ""):
        laser["power"] = 0.001  # the energies stay far below their limits
    got = emission_excess(spans, laser["power"], LaserLimits(**laser["limits"]))
    assert got == text if text is None else (got is not None and text in got), got


def test_no_limits_or_no_power_checks_nothing_but_max_on() -> None:
    assert emission_excess([[0, 100.0]], None, LaserLimits()) is None
    assert emission_excess([[0, 100.0]], None, LaserLimits(max_spot_energy=1e-6)) is None
    assert "max_on" in (emission_excess([[0, 3.0]], None, LaserLimits(max_on=2.0)) or "")


def test_execution_refuses_a_trajectory_over_a_limit_without_sending_it() -> None:
    sent: list[Any] = []
    ex = Execution(("arm0",), lambda r, b: sent.append((r, b)), lambda why: None, None, None, 1.0)  # type: ignore[arg-type]
    laser = {"world_T_laser": {}} | LASER
    plan = as_plan({"robots": ["arm0"], "scenario": {"system": {"laser": laser}},
                    "trajectory": {"t": [0.0, 2.0], "laser_on": [[0.5, 1.9]]}})  # fmt: skip
    plan = ex.execute(plan, "r1", "S")
    assert plan.execution is Verdict.REJECTED and not sent
    assert "not sent: the exposure from t = 0.500 s delivers 0.07 J" in str(plan.execution_reason)
