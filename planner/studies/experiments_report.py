"""The figures, plot and report.md of ``study experiments`` (from the trials' rows).

Statistics: per experiment, mean ± std of the errors of every measured target over all
trials (as the paper pools its measurements), and the 95 % confidence interval of the mean
over trials (Student t on the per-trial means: each trial is an independent seeded cell).
The paper's Fig. 6 compares the chessboard placements with two-sample t-tests: the same
tests on the pooled per-target errors of each pair of placements.
"""

from __future__ import annotations

from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from planner.studies import common
from planner.studies import experiments_setup as setup
from planner.studies.experiments_metrics import mean_ci, two_sample_t

PAPER_MM = {"chessboard": (1.61, 0.77), "curve": (3.61, 1.58), "face": (3.29, 1.72),
            "finger": (2.65, 1.13)}  # fmt: skip
"""The paper's real-robot tracking errors, mean ± std (mm)."""
PAPER_CALIBRATION_MM = {"handeye": (1.13, 0.50), "beam": (2.04, 1.25)}
PAPER_IK_TIME_S = (0.020, 0.022)
LOOPS = ("open", "closed", "true_open", "true_closed")


def _errors(rows: list[dict[str, Any]], key: str, loop: str) -> tuple[np.ndarray, list[float]]:
    """Pooled errors (mm) of the ok rows whose ``group`` or ``experiment`` is ``key``, and
    the per-trial means."""
    sel = [r for r in rows if key in (r["group"], r["experiment"]) and r["status"] == "ok"]
    e = np.array([r[f"{loop}_mm"] for r in sel], dtype=float)
    trials = sorted({r["trial"] for r in sel})
    per = [float(np.nanmean([r[f"{loop}_mm"] for r in sel if r["trial"] == t])) for t in trials]
    return e[np.isfinite(e)], per


def _cell(e: np.ndarray, per: list[float]) -> dict[str, float]:
    ci = mean_ci(per)
    return {"mean_mm": float(np.mean(e)) if len(e) else float("nan"),
            "median_mm": float(np.median(e)) if len(e) else float("nan"),
            "over_5mm": int(np.sum(e > 5.0)),
            "std_mm": float(np.std(e, ddof=1)) if len(e) > 1 else float("nan"),
            "ci95_mm": ci.half_width, "n": len(e)}  # fmt: skip


def summarize(trials: list[dict[str, Any]]) -> dict[str, Any]:
    """Every figure of the report (and of ``--json``)."""
    rows = [r for t in trials for r in t["rows"]]
    keys = [*setup.GROUPS, *(f"chessboard {p}" for p in setup.CHESSBOARD)]
    table = []
    for key in keys:
        n_all = sum(1 for r in rows if key in (r["group"], r["experiment"]))
        entry: dict[str, Any] = {"experiment": key, "targets": n_all}
        for loop in LOOPS:
            entry[loop] = _cell(*_errors(rows, key, loop))
        entry["paper"] = PAPER_MM.get(key)
        table.append(entry)
    tests = []
    for a, b in combinations(setup.CHESSBOARD, 2):
        for loop in LOOPS[:2]:
            t = two_sample_t(_errors(rows, f"chessboard {a}", loop)[0],
                             _errors(rows, f"chessboard {b}", loop)[0])  # fmt: skip
            tests.append({"pair": f"{a}-{b}", "loop": loop, **t._asdict()})
    times = np.array([r["ik_time_s"] for r in rows if np.isfinite(r["ik_time_s"])])
    iters = np.array([r["servo_iterations"] for r in rows if r["status"] == "ok"])
    calib = {k: mean_ci([t[f"{k}_residual_mm"] for t in trials])._asdict()
             for k in ("handeye", "beam")}  # fmt: skip
    return {"experiments": table, "t_tests": tests, "calibration_residual_mm": calib,
            "ik_time_s": {"mean": float(times.mean()), "std": float(times.std(ddof=1)),
                          "median": float(np.median(times)), "n": len(times)},
            "servo_iterations_mean": float(iters.mean()) if len(iters) else float("nan"),
            "status": {s: sum(r["status"] == s for r in rows)
                       for s in ("ok", "hidden", "unsolved", "lost")}}  # fmt: skip


def plot(trials: list[dict[str, Any]], path: Path) -> None:
    """(a) per experiment: open / closed loop errors (box) and the paper's mean ± std;
    (b) the chessboard placements (the paper's Fig. 6)."""
    rows = [r for t in trials for r in t["rows"]]
    plt = common.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), gridspec_kw={"width_ratios": [4, 3]})
    for ax, keys in (
        (axes[0], setup.GROUPS),
        (axes[1], [f"chessboard {p}" for p in setup.CHESSBOARD]),
    ):
        x = np.arange(len(keys))
        for dx, loop, color in ((-0.2, "open", "tab:blue"), (0.2, "closed", "tab:green")):
            data = [_errors(rows, k, loop)[0] for k in keys]
            bp = ax.boxplot(data, positions=x + dx, widths=0.3, showfliers=False,
                            patch_artist=True)  # fmt: skip
            for b in bp["boxes"]:
                b.set_facecolor(color)
                b.set_alpha(0.5)
            ax.plot([], [], "s", color=color, alpha=0.5, label=f"{loop} loop (sim)")
        for i, k in enumerate(keys):
            if k in PAPER_MM:
                m, s = PAPER_MM[k]
                ax.errorbar(i + 0.45, m, yerr=s, fmt="rs", ms=4, capsize=3,
                            label="paper (real)" if i == 0 else None)  # fmt: skip
        ax.set_xticks(x, [k.replace("chessboard ", "placement ") for k in keys])
        ax.set_ylabel("spot error (mm)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_title("tracking experiments, end to end")
    axes[1].set_title("chessboard placements (Fig. 6)")
    common.save_figure(fig, path)
