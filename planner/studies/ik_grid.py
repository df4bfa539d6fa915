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

from planner.data import shipped_scenario
from planner.errors import InputError
from planner.studies import common

TRIALS = 10  # paper scale
SCENARIO = shipped_scenario("paper_n1.yaml")
PAPER = "typically < 1e-5 mm, max < 5e-4 mm (paper Fig. 3a)"


def perturb(T: Any, rng: Any, deg: float = 5.0, mm: float = 10.0) -> Any:
    """``T`` moved by U(-1,1)*deg about each axis (rpy) and U(-1,1)*mm along each axis."""
    from planner.model.transforms import make_T, rpy_to_matrix

    d = make_T(rpy_to_matrix(rng.uniform(-1, 1, 3) * 3.141592653589793 / 180 * deg),
               rng.uniform(-1, 1, 3) * mm * 1e-3)  # fmt: skip
    return T @ d


def run_trial(scenario: str, seed: int, trial: int) -> dict[str, Any]:
    """One trial: perturbed geometry, every grid target solved from the previous one."""
    import numpy as np

    from planner.ik import BeamIK
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.planning import ik_options

    loaded = load_scenario(scenario)
    nominal = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, nominal)
    rng = common.trial_rng(seed, trial)
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


def plot(errors_mm: Any, path: Path) -> None:
    """Histogram of log10 spot error (mm) with the paper's maximum marked."""
    import numpy as np

    plt = common.pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.hist(np.log10(np.maximum(errors_mm, 1e-18)), bins=50)
    ax.axvline(np.log10(5e-4), color="red", ls="--", label="paper max 5e-4 mm")
    ax.set_xlabel("log10 spot error [mm]")
    ax.set_ylabel("targets")
    ax.legend()
    common.save_figure(fig, path, dpi=120)


def main(
    trials: int,
    seed: int,
    out: Path,
    workers: int | None,
    sched: str | None,
    scenario: Path = SCENARIO,
) -> dict[str, Any]:
    """Run the study and write its report; returns the ``--json`` figures."""
    import numpy as np

    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}", str(scenario))
    jobs = [(str(scenario), seed, t) for t in range(trials)]
    rows = common.parallel_map(run_trial, jobs, workers=workers, scheduler=sched, label="ik-grid")
    all_e = np.concatenate([np.asarray(r.pop("_errors_mm")) for r in rows])
    all_e = all_e[np.isfinite(all_e)]
    plot(all_e, common.out_dir(out) / "errors.png")
    figures = {
        "study": "ik-grid",
        "trials": trials,
        "seed": seed,
        "targets": int(sum(r["targets"] for r in rows)),
        "solved": int(sum(r["solved"] for r in rows)),
        "error_median_mm": float(np.median(all_e)) if all_e.size else None,
        "error_max_mm": float(np.max(all_e)) if all_e.size else None,
    }
    lines = [
        "# IK grid (paper Fig. 3a)",
        "",
        f"Scenario `{scenario.name}`, {trials} trials, seed {seed}; laser pose and mirror mount "
        "perturbed by U(-1,1)*(5 deg, 10 mm).",
        "",
        common.markdown_table(rows),
        f"Overall: {figures['solved']}/{figures['targets']} solved, error median "
        f"{figures['error_median_mm']:.3g} mm, max {figures['error_max_mm']:.3g} mm. "
        f"Paper: {PAPER}.",
        "",
        "![errors](errors.png)",
        "",
    ]
    common.write_report(out, lines, {"trials.csv": rows})
    typer.echo(common.markdown_table(rows))
    return figures


def command(
    trials: common.Trials = TRIALS,
    seed: common.Seed = 0,
    out: common.Out = Path("reports/ik-grid"),
    scenario: Annotated[Path, typer.Option("--scenario", help="Grid scenario.")] = SCENARIO,
    workers: common.Workers = None,
    dask_scheduler: common.Scheduler = None,
    json_out: common.JsonOut = False,
) -> None:
    """Paper Fig. 3a: IK error over the 1000-point grid under perturbed geometry."""
    common.finish(out, main(trials, seed, out, workers, dask_scheduler, scenario), json_out)
