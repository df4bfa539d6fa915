"""``beamrelay study experiments-n2``: the N = 2 relay end to end on the simulated cell.

Per trial (seeded, independent of how many run and where), on ``scenarios/n2_relay.yaml``:

1. a hidden TRUE relay (:func:`planner.studies.n2_setup.draw_truth`: laser, both mirror
   mounts, camera, hand-eye board, arm1's placement); the planner starts from the nominal
   scenario;
2. the chained calibration on the simulated cell (:func:`planner.studies.n2_setup.calibrate_relay`:
   hand-eye on each arm, then mirror 1 with arm1 out of the beam, then mirror 2 with the
   laser and mirror 1 held), and its errors against the truth
   (:func:`planner.studies.n2_setup.calibration_errors`);
3. each experiment (chessboard corners, point to point; a sine curve, closest point) run as
   the N = 1 experiments run (:func:`planner.studies.experiments_trial.run_experiment`):
   targets measured by the camera, planned with :class:`planner.ik.BeamIK` on the calibrated
   relay, executed on the truth, the spot measured by the camera (open loop), then the
   product's servo (:mod:`planner.servo`, both arms' joints) and an independent measurement
   (closed loop).

Then the spot's sensitivity to each mirror's error (:mod:`planner.studies.n2_sensitivity`).
Statistics: mean over per-trial means with a 95 % CI (Student t over trials,
:func:`planner.studies.experiments_metrics.mean_ci`). Units: mm, degrees.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from planner.studies import common
from planner.studies import n2_sensitivity as sens
from planner.studies import n2_setup as setup
from planner.studies.experiments_metrics import mean_ci
from planner.studies.experiments_report import per_trial, pooled
from planner.studies.experiments_setup import Effects
from planner.studies.provenance import stamp
from schemas.defaults import SERVO_TOLERANCE_M

TRIALS = 6  # `study all`: 21 s CPU; 35 s wall on the 2 shared cores at load 7, 68 s at load 9
EXPERIMENTS = ("chessboard", "curve")
LOOPS = ("open", "closed", "true_open", "true_closed")
CAL_FIGURES = {
    "laser_deg": "laser direction (deg)", "laser_mm": "laser line offset (mm)",
    "mirror1_deg": "mirror 1 normal (deg)", "mirror1_mm": "mirror 1 plane offset (mm)",
    "mirror2_deg": "mirror 2 normal (deg)", "mirror2_mm": "mirror 2 plane offset (mm)",
    "arm1_base_mm": "arm1 base origin (mm)", "camera_mm": "camera origin (mm)",
    "handeye_residual_mm": "hand-eye residual, both arms (mm)",
    "mirror1_residual_mm": "mirror 1 spot residual (mm)",
    "mirror2_residual_mm": "mirror 2 spot residual (mm)",
}  # fmt: skip
"""Calibration figures of a trial -> their label in the report."""
IMPERFECT = Effects(camera_noise=True, depth_bias=True, robot="factory")
"""``--imperfect``: the N = 1 error budget's effects that apply to a relay at rest: the
D435's correlated pixel noise and its disparity bias, both arms off their nominal model at
the factory spread (no servo lag: the targets are points and a curve measured at rest)."""


def run_trial(seed: int, trial: int, closed_loop: bool = True,
              unknowns: setup.RelayUnknowns | None = None,
              imperfect: bool = False) -> dict[str, Any]:  # fmt: skip
    """One trial: its calibration figures and every target's row (``trial`` added); with
    ``imperfect`` on the cell of :data:`IMPERFECT`."""
    from planner.ik import BeamIK
    from planner.plan.scenario_planner import ik_options
    from planner.studies.experiments_trial import ClosedLoop, run_experiment

    rng = common.trial_rng(seed, trial)
    nominal = setup.nominal_system()
    effects = IMPERFECT if imperfect else None
    truth = setup.draw_truth(
        nominal, unknowns or setup.RelayUnknowns(), rng, effects, [seed, trial]
    )
    cal = setup.calibrate_relay(nominal, truth, rng)
    figures = setup.calibration_errors(cal.system, truth.system)
    figures["handeye_residual_mm"] = 1e3 * float(np.mean(cal.handeye_residuals))
    for i, b in enumerate(cal.beams):
        figures[f"mirror{i + 1}_residual_mm"] = 1e3 * float(np.mean(b.residuals))
        figures[f"mirror{i + 1}_spots"] = len(b.residuals)
    ik = BeamIK(cal.system, ik_options(setup.scenario_model().model.solver))
    closed = ClosedLoop(cal) if closed_loop else None
    rows = []
    for i, exp in enumerate(setup.experiments()):
        for r in run_experiment(exp, cal, truth, ik, closed, [seed, trial, i]):
            rows.append({"trial": trial, **r})
    return {"trial": trial, **figures, "rows": rows}


def run(trials: int, seed: int, workers: int | None = None, scheduler: str | None = None,
        imperfect: bool = False) -> tuple[list[dict[str, Any]], Any, list[dict[str, Any]]]:  # fmt: skip
    """Every trial (parallel over trials), then the sensitivity at the same trial count:
    (trial results, the sensitivity's nominal solution, its rows)."""
    jobs = [(seed, t, True, None, imperfect) for t in range(trials)]
    results = common.parallel_map(run_trial, jobs,
                                  workers=workers, scheduler=scheduler, label="relay trials")  # fmt: skip
    nominal = sens.solve_nominal()
    per = common.parallel_map(sens.trial_rows, [(nominal, t, seed) for t in range(trials)],
                              workers=workers, scheduler=scheduler, label="relay sensitivity")  # fmt: skip
    return results, nominal, [r for rows in per for r in rows]


def accuracy(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per experiment and loop: mean over per-trial means ± 95 % CI, and pooled figures."""
    out = []
    for exp in EXPERIMENTS:
        row: dict[str, Any] = {"experiment": exp}
        row["targets"] = sum(r["experiment"] == exp for r in rows)
        row["measured"] = sum(r["experiment"] == exp and r["status"] == "ok" for r in rows)
        for loop in LOOPS:
            ci = mean_ci(list(per_trial(rows, exp, loop).values()))
            e = pooled(rows, exp, loop)
            row |= {f"{loop}_mm": ci.mean, f"{loop}_ci95_mm": ci.half_width,
                    f"{loop}_max_mm": float(e.max()) if len(e) else float("nan")}  # fmt: skip
        ok = [r["servo_iterations"] for r in rows if r["experiment"] == exp and r["status"] == "ok"]
        row["servo_steps"] = float(np.mean(ok)) if ok else float("nan")
        out.append(row)
    return out


def calibration_summary(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per calibration figure: mean over trials ± 95 % CI, and the worst trial."""
    out = []
    for key, label in CAL_FIGURES.items():
        v = np.array([r[key] for r in results], dtype=float)
        ci = mean_ci(v)
        out.append({"figure": label, "key": key, "mean": ci.mean, "ci95": ci.half_width,
                    "max": float(np.max(v))})  # fmt: skip
    return out


def plot(rows: list[dict[str, Any]], sens_summary: list[dict[str, Any]], path: Path) -> None:
    """Left: per-target errors open / closed loop per experiment; right: the spot's RMS
    error per unit error of each part (first order)."""
    plt = common.pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.6))
    data, labels = [], []
    for exp in EXPERIMENTS:
        for loop in ("open", "closed"):
            data.append(pooled(rows, exp, loop))
            labels.append(f"{exp}\n{loop}")
    a.boxplot(data, showfliers=True, flierprops={"markersize": 2})
    a.set_xticks(range(1, len(labels) + 1), labels, fontsize=8)
    a.set_ylabel("spot error (mm)")
    a.set_title("relay accuracy (camera-measured)")
    a.grid(alpha=0.3)
    per = {s["group"]: s for s in sens_summary}  # the last level's row of each group
    for unit in ("deg", "mm"):
        names = [g for g, s in per.items() if s["unit"] == unit]
        b.bar(names, [per[g]["per_unit"] for g in names], label=f"mm per {unit}")
    b.set_ylabel("spot RMS error per unit error (mm)")
    b.set_yscale("log")
    b.tick_params(axis="x", labelrotation=30, labelsize=8)
    b.set_title("sensitivity (first order)")
    b.legend(fontsize=7)
    common.save_figure(fig, path)


def report_lines(results: list[dict[str, Any]], acc: list[dict[str, Any]],
                 cal: list[dict[str, Any]], sens_summary: list[dict[str, Any]],
                 trials: int, seed: int, imperfect: bool = False) -> list[str]:  # fmt: skip
    """The markdown report (see the module docstring)."""
    cell = (f"an imperfect cell ({IMPERFECT.describe()})" if imperfect else "the kind "
            "simulation (independent D435 pixel noise, no depth bias, exact arms; "
            "`--imperfect` adds correlated noise, bias and the arms' factory error)")  # fmt: skip
    lines = ["# The N = 2 relay end to end on the simulated cell", "",
             f"{trials} trials, seed {seed}, `scenarios/n2_relay.yaml` (laser -> arm0's mirror -> "
             f"arm1's mirror -> targets behind a screen). Unknowns before calibration (uniform "
             f"per component): {setup.RelayUnknowns().describe()}. Calibration, with the "
             "product's code on the simulated D435: hand-eye on arm0 (the camera) and on arm1 "
             "(arm1's placement), then `calibrate_chain`: mirror 1 from 16 poses x 3 boards with "
             "arm1 out of the beam (laser line + mirror 1 plane), then mirror 2 from 16 poses x 3 "
             f"boards with the laser and mirror 1 held at their calibrated values. Cell: {cell}.", "",
             "## Calibration against the truth", "",
             "Mean over trials ± 95 % CI (Student t), and the worst trial. Only what moves the "
             "beam is compared: laser line, mirror planes at home (the gauge directions are "
             "left out). The parts are fitted together, so their errors are correlated and "
             "partly cancel at the spot: the accuracy below, not the sum of each part's error "
             "times its sensitivity, is what a target sees.", ""]  # fmt: skip
    lines += common.table_lines(["figure", "mean ± 95 % CI", "worst trial"], cal,
                                "{figure} | {mean:.4f} ± {ci95:.4f} | {max:.4f}")  # fmt: skip
    spots = [f"{np.mean([r[f'mirror{i}_spots'] for r in results]):.1f}" for i in (1, 2)]
    lines += ["", f"Spots per trial seen and used: mirror 1 {spots[0]}, mirror 2 {spots[1]} "
              "(of 48 planned each).", "", "## Accuracy, open and closed loop", "",
              "Mean over the per-trial means ± 95 % CI (Student t over trials), mm; worst "
              "target in brackets. Camera: spot and target as the camera measured them (the "
              "paper's metric: point to point for the chessboard, closest point to the "
              "measured curve); true: the true spot against the true target.", ""]  # fmt: skip
    header = ["experiment", "measured", "open loop", "closed loop", "true open", "true closed",
              "servo steps"]  # fmt: skip
    row = "{experiment} | {measured}/{targets} | {open_mm:.3f} ± {open_ci95_mm:.3f} "
    row += "[{open_max_mm:.2f}] | {closed_mm:.3f} ± {closed_ci95_mm:.3f} [{closed_max_mm:.2f}] | "
    row += "{true_open_mm:.3f} ± {true_open_ci95_mm:.3f} | {true_closed_mm:.3f} ± "
    row += "{true_closed_ci95_mm:.3f} | {servo_steps:.2f}"
    lines += common.table_lines(header, acc, row)
    lines += ["", f"The servo (`planner.servo`, default settings, all 12 joints) stops within "
              f"{1e3 * SERVO_TOLERANCE_M:g} mm of the measured target, so where the open loop "
              "is already near that it changes little; servo steps: correction steps per "
              "target."]  # fmt: skip
    lines += ["", "## Sensitivity of the spot to each mirror's error", "",
              f"{trials} draws per group and level on the scenario's {sens.TARGETS_TEXT}. "
              "Sampled: the nominal joints traced with the perturbed relay; pred RMS = "
              "level·‖J‖_F/√3 from the CasADi graph; mm per unit = pred RMS / level; max "
              "rel dev = max |first order - sampled| / max sampled.", ""]  # fmt: skip
    lines += sens.table(sens_summary)
    u = setup.RelayUnknowns().shared
    lines += ["", sens.verdict(sens_summary, np.degrees(u.mirror_rot), 1e3 * u.mirror_pos), ""]
    return lines


def write(out: Path, results: list[dict[str, Any]], nominal: Any,
          sens_rows: list[dict[str, Any]], trials: int, seed: int,
          imperfect: bool = False) -> dict[str, Any]:  # fmt: skip
    """CSV tables, the plot and report.md; returns the figures printed with ``--json``."""
    rows = [r for res in results for r in res["rows"]]
    acc, cal = accuracy(rows), calibration_summary(results)
    sens_summary = sens.summarize(nominal, sens_rows)
    plot(rows, sens_summary, common.out_dir(out) / "experiments_n2.png")
    lines = report_lines(results, acc, cal, sens_summary, trials, seed, imperfect)
    trial_figs = [{k: v for k, v in r.items() if k != "rows"} for r in results]
    tables = {"experiments_n2.csv": rows, "calibration.csv": trial_figs,
              "sensitivity.csv": sens_rows, "sensitivity_summary.csv": sens_summary}  # fmt: skip
    common.write_report(out, lines, tables, image=("relay accuracy and sensitivity",
                                                   "experiments_n2.png"))  # fmt: skip
    return {"study": "experiments-n2", "trials": trials, "seed": seed, "imperfect": imperfect, "accuracy": acc,
            "calibration": cal, "sensitivity": sens_summary}  # fmt: skip


def main(trials: int, seed: int, out: Path, workers: int | None, sched: str | None,
         imperfect: bool = False) -> dict:  # fmt: skip
    """The N = 2 relay end to end: chained calibration, open/closed loop accuracy, each
    mirror's sensitivity."""
    return write(out, *run(trials, seed, workers, sched, imperfect), trials, seed, imperfect)


Imperfect = Annotated[bool, typer.Option("--imperfect", help="Correlated D435 noise, its depth "
                                         "bias and both arms' factory kinematic error.")]  # fmt: skip


def command(
    trials: common.Trials = TRIALS,
    seed: common.Seed = 0,
    out: common.Out = Path("reports/experiments-n2"),
    workers: common.Workers = None,
    dask_scheduler: common.Scheduler = None,
    json_out: common.JsonOut = False,
    imperfect: Imperfect = False,
) -> None:
    t0 = time.perf_counter()
    figures = main(trials, seed, out, workers, dask_scheduler, imperfect)
    flags = " --imperfect" if imperfect else ""
    stamp(out / "report.md", f"beamrelay study experiments-n2 --trials {trials} --seed {seed}"
          f" -o {out}{flags}", trials, seed, time.perf_counter() - t0)  # fmt: skip
    common.finish(out, figures, json_out)


command.__doc__ = main.__doc__
