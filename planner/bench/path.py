"""``beamrelay bench path``: path-tracking NLP time for K = 100, 1000, 5000 samples.

The shipped ``scenarios/curve_path.yaml`` curve is resampled so that it has exactly K
samples; each K builds its own NLP (build time reported separately), warm-started from the
continuation chain. Figures are printed, not asserted.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from planner.data import shipped_scenario

DEFAULT_SCENARIO = shipped_scenario("curve_path.yaml")


# long: a typer command: it times the path NLP for each sample count K and prints one table
def command(
    scenario: Annotated[Path, typer.Option(help="Path scenario to sweep.")] = DEFAULT_SCENARIO,
    sizes: Annotated[str, typer.Option(help="Comma-separated sample counts K.")] = "100,1000,5000",
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON (last line).")] = False,
) -> None:
    """Path NLP time (build + solve) and warm start for several sample counts."""
    import numpy as np
    from rich.console import Console
    from rich.progress import track
    from rich.table import Table

    from planner.errors import InputError
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.model.polyline import arc_length, resample_polyline
    from planner.model.system import Targets
    from planner.path.solve import plan_path
    from planner.plan.scenario_planner import path_seeder

    try:
        Ks = [int(k) for k in sizes.split(",")]
    except ValueError as exc:
        raise InputError(f"--sizes must be integers: {sizes!r}") from exc
    if not Ks or min(Ks) < 2:
        raise InputError(f"--sizes {sizes!r}: every sample count K must be >= 2")
    loaded = load_scenario(scenario)
    system = system_from_scenario(loaded)
    base = targets_from_scenario(loaded, system)
    length = float(arc_length(base.points)[-1])
    rows = []
    for K in track(Ks, description="path NLP", console=Console(stderr=True)):
        pts, nrm = resample_polyline(
            base.points, length / (K - 1) * (1 - 1e-9), False, base.normals
        )
        pts, nrm = pts[:K], None if nrm is None else nrm[:K]
        res = plan_path(system, Targets(pts, nrm, kind="path"), seeder=path_seeder(system))
        seg = max(res.segments, key=lambda s: s.k1 - s.k0)
        rows.append({
            "K": len(pts), "warm_s": res.warm_time, "nlp_build_s": seg.build_time,
            "nlp_solve_s": res.nlp_time - seg.build_time, "nlp_total_s": res.nlp_time,
            "iterations": seg.iterations, "status": seg.status,
            "error_max_m": float(np.nanmax(res.error)), "gaps": len(res.gaps),
        })  # fmt: skip
    table = Table(title=f"path NLP ({scenario.name}, {length * 1e3:.1f} mm)")
    for col in (
        "K",
        "warm s",
        "build s",
        "solve s",
        "NLP total s",
        "iter",
        "max error m",
        "status",
    ):
        table.add_column(col)
    for r in rows:
        table.add_row(
            str(r["K"]), f"{r['warm_s']:.3f}", f"{r['nlp_build_s']:.3f}", f"{r['nlp_solve_s']:.3f}",
            f"{r['nlp_total_s']:.3f}", str(r["iterations"]), f"{r['error_max_m']:.2e}", str(r["status"]),
        )  # fmt: skip
    Console().print(table)
    if as_json:
        print(json.dumps({"bench": "path", "scenario": str(scenario), "rows": rows}))
