"""``beamrelay study ik-grid``: the paper's Fig. 3a simulation IK test.

Per trial the laser pose and ``flange_T_mirror`` are perturbed by U(-1, 1) * (5 deg, 10 mm)
per component (a different but exactly known geometry), the scenario's grid (1000 points in
a 100 mm cube for ``paper_n1.yaml``) is solved, and the spot errors are reported per trial
and overall next to the paper's "typically < 1e-5 mm, max < 5e-4 mm".
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from planner.studies.common import markdown_table, out_dir, parallel_map, trial_rng, write_csv

ROOT = Path(__file__).resolve().parents[2]
PAPER = "typically < 1e-5 mm, max < 5e-4 mm (paper Fig. 3a)"


def perturb(T: Any, rng: Any, deg: float = 5.0, mm: float = 10.0) -> Any:
    """``T`` moved by U(-1,1)*deg about each axis (rpy) and U(-1,1)*mm along each axis."""
    from planner.transforms import make_T, rpy_to_matrix

    d = make_T(rpy_to_matrix(rng.uniform(-1, 1, 3) * 3.141592653589793 / 180 * deg),
               rng.uniform(-1, 1, 3) * mm * 1e-3)  # fmt: skip
    return T @ d


def run_trial(scenario: str, seed: int, trial: int) -> dict[str, Any]:
    """One trial: perturbed geometry, every grid target solved from the previous one."""
    import numpy as np

    from planner.ik import BeamIK
    from planner.planning import ik_options
    from planner.scenario import load_scenario, system_from_scenario, targets_from_scenario

    loaded = load_scenario(scenario)
    nominal = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, nominal)
    rng = trial_rng(seed, trial)
    system = nominal.with_params(
        world_T_laser=perturb(nominal.world_T_laser, rng),
        flange_T_mirror={r.name: perturb(r.mirror.flange_T_mirror, rng) for r in nominal.robots},
    )
    ik = BeamIK(system, ik_options(loaded.model.solver))
    q, errors, times, reasons = system.home, [], [], []
    for k in range(len(targets)):
        sol = ik.solve(targets.points[k], targets.normal(k), q)
        if sol.q is not None:
            q = sol.q
            errors.append(sol.error)
            times.append(sol.solve_time)
        else:
            reasons.append(sol.reason)
    e = np.array(errors) * 1e3 if errors else np.array([np.nan])
    return {
        "trial": trial,
        "targets": len(targets),
        "solved": len(errors),
        "error_median_mm": float(np.median(e)),
        "error_p99_mm": float(np.percentile(e, 99)),
        "error_max_mm": float(np.max(e)),
        "time_median_ms": float(np.median(times) * 1e3) if times else float("nan"),
        "failures": ";".join(sorted(set(map(str, reasons)))),
        "_errors_mm": e.tolist(),
    }


def command(
    trials: Annotated[int, typer.Option("--trials", min=1, help="Random trials.")] = 10,
    seed: Annotated[int, typer.Option("--seed", help="Seed of every random draw.")] = 0,
    out: Annotated[Path, typer.Option("-o", "--out", help="Output folder.")] = Path(
        "reports/ik-grid"
    ),
    scenario: Annotated[Path, typer.Option("--scenario", help="Grid scenario.")] = ROOT
    / "scenarios"
    / "paper_n1.yaml",
    workers: Annotated[int, typer.Option("--workers", min=1, help="Local processes.")] = 1,
    dask_scheduler: Annotated[
        str | None, typer.Option("--dask-scheduler", help="Dask cluster, tcp://host:8786.")
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Figures as one JSON line.")] = False,
) -> None:
    """Paper Fig. 3a: IK error over the 1000-point grid under perturbed geometry."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from rich.console import Console

    from planner.errors import InputError

    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}")
    folder = out_dir(out)
    jobs = [(str(scenario), seed, t) for t in range(trials)]
    rows = parallel_map(run_trial, jobs, workers=workers, scheduler=dask_scheduler)
    all_e = np.concatenate([np.asarray(r.pop("_errors_mm")) for r in rows])
    all_e = all_e[np.isfinite(all_e)]
    write_csv(folder / "trials.csv", rows)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(np.log10(np.maximum(all_e, 1e-18)), bins=50)
    ax.axvline(np.log10(5e-4), color="red", ls="--", label="paper max 5e-4 mm")
    ax.set_xlabel("log10 spot error [mm]")
    ax.set_ylabel("targets")
    ax.legend()
    fig.tight_layout()
    fig.savefig(folder / "errors.png", dpi=120)
    plt.close(fig)
    figures = {
        "trials": trials,
        "targets": int(sum(r["targets"] for r in rows)),
        "solved": int(sum(r["solved"] for r in rows)),
        "error_median_mm": float(np.median(all_e)) if all_e.size else None,
        "error_max_mm": float(np.max(all_e)) if all_e.size else None,
    }
    (folder / "report.md").write_text(
        f"# IK grid (paper Fig. 3a)\n\nScenario `{scenario.name}`, {trials} trials, seed "
        f"{seed}; laser pose and mirror mount perturbed by U(-1,1)*(5 deg, 10 mm).\n\n"
        + markdown_table(rows)
        + f"\nOverall: {figures['solved']}/{figures['targets']} solved, error median "
        f"{figures['error_median_mm']:.3g} mm, max {figures['error_max_mm']:.3g} mm. "
        f"Paper: {PAPER}.\n\n![errors](errors.png)\n"
    )
    Console().print(markdown_table(rows))
    typer.echo(f"report: {folder / 'report.md'}")
    if json_out:
        print(json.dumps(figures))
