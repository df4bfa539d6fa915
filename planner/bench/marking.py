"""``beamrelay bench marking``: marking figures of path scenarios (laser gate, sky-writing).

Per scenario (default: the shipped curve and S-curve): the largest spot deviation while the
laser is on (from the sampled path and from the scenario's own polyline), the marked spot
speed's min/max as % of the spot speed, the total trajectory time with sky-writing and
without (every stroke marked from rest to rest, the old behaviour), the fluence uniformity
(max/min = the marked speed's max/min), strokes and sharp corners, the approach time and
the arm's Jacobian condition number. Figures come from ``beamrelay check``'s own checks on
the plan; they are printed, not asserted.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.data import shipped_scenario

DEFAULTS = (shipped_scenario("curve_path.yaml"), shipped_scenario("s_curve.yaml"))
COLUMNS = (("samples", "{}"), ("strokes", "{}"), ("sharp_corners", "{}"),
           ("laser_on_deviation_max_m", "mm"), ("polyline_deviation_max_m", "mm"),
           ("marked_speed_min_pct", "{:.2f} %"), ("marked_speed_max_pct", "{:.2f} %"),
           ("fluence_max_over_min", "{:.4f}"), ("duration_s", "{:.3f} s"),
           ("duration_without_skywriting_s", "{:.3f} s"), ("path_time_s", "{:.3f} s"),
           ("approach_time_s", "{:.3f} s"), ("slowdowns", "{:.0f}"),
           ("jacobian_condition_max", "{:.1f}"), ("plan_s", "{:.2f} s"),
           ("violations", "{}"))  # fmt: skip


def marking_figures(scenario: Path) -> dict[str, Any]:
    """The figures of one path scenario (SI units; ratios as fractions)."""
    import time

    from planner.errors import InputError
    from planner.io.scenario import load_scenario
    from planner.model.settings import TrajectorySettings
    from planner.plan.pipeline import run_scenario
    from planner.plan.timed import time_solutions
    from planner.verify.check import check_plan

    if load_scenario(scenario).model.targets.kind != "path":
        raise InputError("needs a path scenario (targets.path)", str(scenario))
    t0 = time.perf_counter()
    o = run_scenario(scenario, progress=False)
    plan_s = time.perf_counter() - t0
    if o.timed is None:
        raise InputError("no sample of the path could be solved", str(scenario))
    results = check_plan(o.doc)
    figures = {f"{r.name}.{k}": v for r in results for k, v in r.figures.items()}
    violations = sum(len(r.findings) for r in results)
    settings = TrajectorySettings.from_mapping(o.doc["scenario"]["trajectory"])
    rest = time_solutions(o.system, o.targets, o.solutions, settings,
                          path=o.path, skywriting=False)  # fmt: skip
    extra = o.doc["metrics"]["extra"]
    lo, hi = (
        figures.get("laser.marked_speed_min_ratio"),
        figures.get("laser.marked_speed_max_ratio"),
    )
    return {
        "scenario": scenario.name,
        "samples": len(o.targets),
        "strokes": len(o.targets.meta.get("strokes") or ()),  # type: ignore[arg-type]
        "sharp_corners": o.targets.meta.get("sharp_corners"),
        "laser_on_deviation_max_m": figures.get("laser.laser_on_deviation_max_m"),
        "polyline_deviation_max_m": figures.get("laser.polyline_deviation_max_m"),
        "marked_speed_min_pct": None if lo is None else 100 * lo,
        "marked_speed_max_pct": None if hi is None else 100 * hi,
        "fluence_max_over_min": None if lo is None or hi is None else hi / lo,
        "duration_s": o.timed.trajectory.duration,
        "duration_without_skywriting_s": None if rest is None else rest.trajectory.duration,
        "path_time_s": extra.get("path_time"),
        "approach_time_s": extra.get("approach_time"),
        "slowdowns": extra.get("slowdowns"),
        "jacobian_condition_max": extra.get("jacobian_condition_max"),
        "plan_s": plan_s,
        "violations": violations,
    }


def command(
    scenario: Annotated[
        list[Path] | None, typer.Option(help="Path scenario(s) (default: curve and S-curve).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON (last line).")] = False,
) -> None:
    """Marking figures: deviation while the laser is on, marked speed, time with and without
    sky-writing, fluence uniformity."""
    from rich.console import Console
    from rich.table import Table

    rows = [marking_figures(Path(s)) for s in (scenario or DEFAULTS)]
    table = Table(title="marking (laser gate, sky-writing)")
    table.add_column("figure")
    for r in rows:
        table.add_column(str(r["scenario"]))
    for name, fmt in COLUMNS:
        cells = []
        for r in rows:
            v = r[name]
            cells.append("-" if v is None else f"{1e3 * v:.4f}" if fmt == "mm" else fmt.format(v))
        label = name.removesuffix("_m").replace("_", " ") + (" (mm)" if fmt == "mm" else "")
        table.add_row(label, *cells)
    Console().print(table)
    if as_json:
        print(json.dumps({"bench": "marking", "rows": rows}))
