"""``beamrelay bench ik [SCENARIO]``: per-target IK time and error, default vs ``--optimal``,
next to the paper's numbers (MATLAB LM: 20 +- 22 ms per target, max error 5e-4 mm).

Figures are printed, never asserted. Every solution is re-verified by :mod:`planner.verify.check`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from planner.data import shipped_scenario

PAPER = {"time_ms": "20 ± 22", "error_max_mm": 5e-4}


def _run(scenario: Path, optimal: bool) -> dict[str, Any]:
    import numpy as np

    from planner.ik import BeamIK
    from planner.io.resolved import resolved_scenario_dict
    from planner.io.scenario import (
        load_scenario,
        system_from_scenario,
        targets_from_scenario,
    )
    from planner.plan.document import plan_document
    from planner.plan.scenario_planner import ik_options
    from planner.verify.check import check_plan

    loaded = load_scenario(scenario)
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    ik = BeamIK(system, ik_options(loaded.model.solver, optimal))
    ik.solve(targets.points[0])  # build lazily-built pieces outside the timing
    if optimal:
        _ = ik.nlp
    q, sols = system.home, []
    for k in range(len(targets)):
        sol = ik.solve(targets.points[k], targets.normal(k), q)
        q = sol.q if sol.q is not None else q
        sols.append(sol)
    ok = [s for s in sols if s.ok]
    t = np.array([s.solve_time for s in ok]) * 1e3
    e = np.array([s.error for s in ok]) * 1e3
    doc = plan_document(system, targets, sols, resolved_scenario_dict(loaded))
    violations = sum(len(r.findings) for r in check_plan(doc, scenario.parent))
    return {
        "scenario": scenario.name,
        "mode": "optimal" if optimal else "default",
        "n_robots": system.n_robots,
        "targets": len(targets),
        "solved": len(ok),
        "time_median_ms": float(np.median(t)) if ok else None,
        "time_p95_ms": float(np.percentile(t, 95)) if ok else None,
        "error_max_mm": float(e.max()) if ok else None,
        "error_median_mm": float(np.median(e)) if ok else None,
        "check_violations": violations,
    }


def command(
    scenario: Annotated[
        list[Path] | None, typer.Argument(help="Scenarios (default paper_n1 and n2_relay).")
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Figures as one JSON line.")] = False,
) -> None:
    """Time and accuracy of the per-target IK (single core), default and --optimal."""
    import json

    from rich.console import Console
    from rich.table import Table

    from planner.errors import InputError

    paths = scenario or [shipped_scenario("paper_n1.yaml"), shipped_scenario("n2_relay.yaml")]
    for p in paths:
        if not p.is_file():
            raise InputError(f"scenario not found: {p}")
    rows = [_run(p, opt) for p in paths for opt in (False, True)]
    table = Table(title="bench ik (paper: 20 ± 22 ms/target, max error 5e-4 mm)")
    cols = ("scenario", "mode", "N", "solved", "median ms", "p95 ms", "max err mm", "check")
    for c in cols:
        table.add_column(c)
    for r in rows:
        table.add_row(
            r["scenario"], r["mode"], str(r["n_robots"]), f"{r['solved']}/{r['targets']}",
            f"{r['time_median_ms']:.3f}", f"{r['time_p95_ms']:.3f}", f"{r['error_max_mm']:.2e}",
            "ok" if r["check_violations"] == 0 else f"{r['check_violations']} violations",
        )  # fmt: skip
    Console().print(table)
    if json_out:
        print(json.dumps({"paper": PAPER, "runs": rows}))
