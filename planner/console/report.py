"""The result text of a plan or execution: counts, duration, failures, measured spots.

Pure: a markdown string from an :class:`~planner.console.operator.Answer` and its
:class:`~planner.console.preview.Preview`. Lengths are printed in mm (labelled), times in s.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.console.operator import Answer
from planner.console.preview import Preview
from planner.console.sweep import Sweep
from planner.io.plan import Plan
from planner.model.status import Status
from planner.model.transforms import Array
from planner.service.client import measured_errors

#: most per-target rows shown
MAX_ROWS = 40


def answer_markdown(answer: Answer, pv: Preview, executed: bool, faults: tuple[str, ...] = ()
                    ) -> str:  # fmt: skip
    """Markdown summary of one reply (see the module docstring); ``faults``: what the robot
    drivers reported wrong after the motion (a stop, a lost heartbeat), shown first."""
    plan = answer.plan
    head = (f"**{pv.n_ok}/{pv.n} targets solved**, trajectory {pv.duration:.2f} s, "
            f"reply in {1e3 * answer.seconds:.0f} ms (request {plan.id})")  # fmt: skip
    lines = [head]
    errors = measured_errors(plan, answer.spots)
    if executed:
        lines.append(execution_line(plan))
        lines += [f"**driver: {f}**" for f in faults]
        measured = [e for e in errors if e is not None]
        if measured and answer.sweep is None:
            lines.append(
                f"measured error: median {1e3 * float(np.median(measured)):.2f} mm, "
                f"max {1e3 * max(measured):.2f} mm over {len(measured)} targets"
            )
        lines += _closed_loop(plan)
        if answer.sweep is not None:
            lines.append(sweep_line(answer.sweep))
    for f in pv.failed[:MAX_ROWS]:
        detail = f": {f.detail}" if f.detail else ""
        lines.append(f"#{f.target} failed: **{f.reason}**{detail}")
    if executed and answer.sweep is None:  # a path's samples: the marked path says it
        lines += _measured_rows(plan, answer.spots, errors)
    return "  \n".join(lines)


def execution_line(plan: Plan) -> str:
    """``execution: ...`` of a reply. A robot whose verdict the planner never heard is
    *waiting*, not rejected: its driver may have accepted late (the planner then sent STOP,
    so a late acceptance brakes); :func:`late_verdict_line` says what it answered."""
    waiting = plan.execution_unanswered or ()
    reason = f" ({plan.execution_reason})" if plan.execution_reason else ""
    if waiting:
        return (f"execution: **waiting for {', '.join(waiting)}** (no verdict heard; STOP sent, "
                f"so a late acceptance brakes){reason}")  # fmt: skip
    return f"execution: **{plan.execution or 'not executed'}**{reason}"


def late_verdict_line(robot: str, ack: Any) -> str:
    """What ``robot``'s driver answered, after the reply, to the request it was waited for."""
    if ack.accepted:
        return f"{robot}: **accepted** (late: the STOP sent meanwhile brakes it)"
    return f"{robot}: **rejected** ({ack.reason or 'no reason given'})"


def sweep_line(sw: Sweep) -> str:
    """``marked path: ...`` — the camera's view of an executed path, in mm."""
    if not len(sw.marked):
        return f"marked path: **no spot seen while the laser was on** ({sw.unlit} with it off)"
    return (f"marked path: {len(sw.marked)} spots with the laser on, covering "
            f"{1e3 * sw.covered:.1f} of {1e3 * sw.length:.1f} mm; distance to the planned path "
            f"median {1e3 * sw.deviation_median:.2f} mm, max {1e3 * sw.deviation_max:.2f} mm; "
            f"{sw.unlit} spots seen with the laser planned off")  # fmt: skip


def _measured_rows(plan: Plan, spots: list[Array | None] | None,
                   errors: list[float | None]) -> list[str]:  # fmt: skip
    out = []
    for k, sol in enumerate(plan.solutions[:MAX_ROWS]):
        if sol.status is not Status.OK:
            continue
        target = int(plan.targets.ids[k])
        p = ", ".join(f"{1e3 * c:.1f}" for c in plan.targets.p[k].tolist())
        spot, err = None if spots is None else spots[k], errors[k]
        if spot is None or err is None:
            out.append(f"#{target} planned ({p}) mm: spot not measured")
        else:
            m = ", ".join(f"{1e3 * c:.1f}" for c in np.asarray(spot).tolist())
            out.append(f"#{target} planned ({p}) measured ({m}) mm, error {1e3 * err:.2f} mm")
    return out


def _closed_loop(plan: Plan) -> list[str]:
    """What the reply says about closed-loop correction, as it says it (free-form)."""
    items: list[tuple[str, Any]] = []
    if plan.closed_loop is not None:
        items.append(("closed_loop", plan.closed_loop.to_document()))
    items += [(k, v) for k, v in plan.metrics.extra.items() if "closed" in k or "servo" in k]
    return [f"{k}: `{v}`"[:300] for k, v in items]
