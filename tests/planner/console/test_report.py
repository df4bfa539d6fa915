"""The result text of a reply: counts, the marked path of an executed path, driver faults."""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.console.operator import Answer
from planner.console.preview import Preview
from planner.console.report import answer_markdown, late_verdict_line, sweep_line
from planner.console.sweep import Sweep
from planner.io.plan import Plan
from tests.planner.service.plans import as_plan


def plan(n: int, **reply: Any) -> Plan:
    targets = [{"id": k, "p": [0.001 * k, 0.0, 0.0]} for k in range(n)]
    sols = [{"target": k, "status": "ok", "error": 0.0} for k in range(n)]
    return as_plan({"id": "abc", "execution": "accepted", "targets": targets, "solutions": sols,
                    "metrics": {"n_ok": n, "n_targets": n, "duration": 2.5}} | reply)  # fmt: skip


def preview(n: int) -> Preview:
    return Preview((), (), np.zeros((0, 3)), 2.5, n, n)


def test_an_executed_path_reports_its_marked_sweep_instead_of_per_sample_rows() -> None:
    p = plan(120)
    sw = Sweep(np.zeros((80, 3)), 12, 0.00031, 0.00092, 0.1184, 0.119)
    text = answer_markdown(Answer(p, 0.4, [None] * 120, sw),
                           preview(120), executed=True)  # fmt: skip
    assert "**120/120 targets solved**" in text and "execution: **accepted**" in text
    assert ("marked path: 80 spots with the laser on, covering 118.4 of 119.0 mm; distance to "
            "the planned path median 0.31 mm, max 0.92 mm; 12 spots seen with the laser "
            "planned off") in text  # fmt: skip
    assert "not measured" not in text  # no row per path sample


def test_points_keep_their_rows_and_driver_faults_come_first() -> None:
    p = plan(2)
    spots = [np.array([0.0, 0.0005, 0.0]), None]
    text = answer_markdown(Answer(p, 0.4, spots), preview(2),
                           executed=True, faults=("arm0: heartbeat lost",))  # fmt: skip
    lines = text.split("  \n")
    assert lines[2] == "**driver: arm0: heartbeat lost**"
    assert "#0 planned (0.0, 0.0, 0.0) measured (0.0, 0.5, 0.0) mm, error 0.50 mm" in text
    assert "#1 planned (1.0, 0.0, 0.0) mm: spot not measured" in text


def test_a_sweep_without_lit_spots_says_so() -> None:
    sw = Sweep(np.zeros((0, 3)), 40, np.nan, np.nan, 0.0, 0.1)
    assert sweep_line(sw) == ("marked path: **no spot seen while the laser was on** "
                              "(40 with it off)")  # fmt: skip


def test_a_verdict_never_heard_reads_waiting_never_rejected() -> None:
    """The planner heard no verdict from arm0 (its reply says rejected, with a stop sent):
    the page says it waits for arm0, and what arm0 answered once its status carries it."""
    from schemas.messages import TrajectoryAck

    p = plan(
        1,
        execution="rejected",
        execution_unanswered=["arm0"],
        execution_reason="no answer from arm0 within 2 s; stop sent",
    )
    text = answer_markdown(Answer(p, 0.4, [None]), preview(1),
                           executed=True)  # fmt: skip
    assert "execution: **waiting for arm0**" in text and "rejected" not in text, text
    late = TrajectoryAck(id="abc", accepted=True, t=1.0)
    assert late_verdict_line("arm0", late) == (
        "arm0: **accepted** (late: the STOP sent meanwhile brakes it)")  # fmt: skip
    refused = TrajectoryAck(id="abc", accepted=False, reason="q[3]: too fast", t=1.0)
    assert late_verdict_line("arm0", refused) == "arm0: **rejected** (q[3]: too fast)"
    heard = plan(1, execution="rejected", execution_reason="arm0: q[3]: too fast")
    text = answer_markdown(Answer(heard, 0.4, [None]),
                           preview(1), executed=True)  # fmt: skip
    assert "execution: **rejected** (arm0: q[3]: too fast)" in text
