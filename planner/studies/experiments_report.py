"""The figures, plot and report.md of ``study experiments`` (from the trials' rows).

Statistics: the targets of one trial share its calibration, so they are not independent
samples; the trial (an independently seeded cell) is. Every mean is the mean over the
per-trial means with its 95 % confidence interval (Student t over trials); the spread (std)
and median are those of the pooled per-target errors, as the paper gives its spread. The
comparisons (the paper's Fig. 6 chessboard placements, and open against closed loop per
experiment) are paired t-tests on the per-trial means, Holm-adjusted over the family; the
paper's pooled two-sample test is given beside them only to show what pooling claims.
"""

from __future__ import annotations

from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from planner.studies import common
from planner.studies import experiments_setup as setup
from planner.studies.experiments_metrics import holm, mean_ci, paired_t, two_sample_t

PAPER_MM = {"chessboard": (1.61, 0.77), "curve": (3.61, 1.58), "face": (3.29, 1.72),
            "finger": (2.65, 1.13)}  # fmt: skip
"""The paper's real-robot tracking errors, mean ± std (mm)."""
PAPER_CALIBRATION_MM = {"handeye": (1.13, 0.50), "beam": (2.04, 1.25)}
PAPER_IK_TIME_S = (0.020, 0.022)
LOOPS = ("open", "closed", "true_open", "true_closed")


def _selected(rows: list[dict[str, Any]], key: str) -> list[dict[str, Any]]:
    """The ok rows whose ``group`` or ``experiment`` is ``key``."""
    return [r for r in rows if key in (r["group"], r["experiment"]) and r["status"] == "ok"]


def pooled(rows: list[dict[str, Any]], key: str, loop: str) -> np.ndarray:
    """The finite errors (mm) of every measured target of ``key`` over all trials."""
    e = np.array([r[f"{loop}_mm"] for r in _selected(rows, key)], dtype=float)
    return e[np.isfinite(e)]


def per_trial(rows: list[dict[str, Any]], key: str, loop: str) -> dict[int, float]:
    """{trial: mean error (mm) of ``key``'s measured targets in that trial} (trials with
    no finite error left out): the independent samples of the statistics."""
    by: dict[int, list[float]] = {}
    for r in _selected(rows, key):
        if np.isfinite(r[f"{loop}_mm"]):
            by.setdefault(int(r["trial"]), []).append(float(r[f"{loop}_mm"]))
    return {t: float(np.mean(v)) for t, v in sorted(by.items())}


def _cell(e: np.ndarray, per: dict[int, float]) -> dict[str, float]:
    """Mean over the per-trial means with its 95 % CI half-width; the spread (std), median
    and count of the pooled per-target errors (as the paper gives its spread)."""
    ci = mean_ci(list(per.values()))
    return {"mean_mm": ci.mean, "ci95_mm": ci.half_width, "trials": ci.n,
            "median_mm": float(np.median(e)) if len(e) else float("nan"),
            "over_5mm": int(np.sum(e > 5.0)),
            "std_mm": float(np.std(e, ddof=1)) if len(e) > 1 else float("nan"),
            "n": len(e)}  # fmt: skip


def _comparison(rows: list[dict[str, Any]], name: str, a: tuple[str, str],
                b: tuple[str, str]) -> dict[str, Any]:  # fmt: skip
    """The paired test of (key, loop) ``a`` against ``b`` on per-trial means, and the pooled
    per-target two-sample test beside it (what pooling would claim)."""
    t = paired_t(per_trial(rows, *a), per_trial(rows, *b))
    old = two_sample_t(pooled(rows, *a), pooled(rows, *b))
    return {"comparison": name, "diff_mm": t.diff.mean, "diff_ci95_mm": t.diff.half_width,
            "t": t.t, "dof": t.dof, "trials": t.n, "p": t.p, "p_holm": float("nan"),
            "pooled_p": old.p, "pooled_dof": old.dof}  # fmt: skip


def comparisons(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The family of tests: the chessboard placements pairwise per loop (the paper's Fig. 6)
    and open against closed loop per experiment, each a paired t-test on per-trial means
    (every trial runs every placement and both loops on one calibration), Holm-adjusted
    over the whole family."""
    tests = [_comparison(rows, f"chessboard {a} - {b}, {loop} loop",
                         (f"chessboard {a}", loop), (f"chessboard {b}", loop))
             for a, b in combinations(setup.CHESSBOARD, 2) for loop in LOOPS[:2]]  # fmt: skip
    tests += [_comparison(rows, f"{g}: open - closed loop", (g, "open"), (g, "closed"))
              for g in setup.GROUPS]  # fmt: skip
    for t, p in zip(tests, holm([t["p"] for t in tests]), strict=True):
        t["p_holm"] = float(p)
    return tests


def _trial_mean_ci(rows: list[dict[str, Any]], key: str, ok: set[str]) -> dict[str, float]:
    """Mean of ``key`` over the per-trial means of the rows whose status is in ``ok`` (and
    whose value is finite), its 95 % CI half-width and the number of rows."""
    by: dict[int, list[float]] = {}
    for r in rows:
        if r["status"] in ok and np.isfinite(r[key]):
            by.setdefault(int(r["trial"]), []).append(float(r[key]))
    ci = mean_ci([np.mean(v) for v in by.values()])
    v = np.array([x for vs in by.values() for x in vs])
    return {"mean": ci.mean, "ci95": ci.half_width, "trials": ci.n, "n": len(v),
            "std": float(np.std(v, ddof=1)) if len(v) > 1 else float("nan"),
            "median": float(np.median(v)) if len(v) else float("nan")}  # fmt: skip


def summarize(trials: list[dict[str, Any]]) -> dict[str, Any]:
    """Every figure of the report (and of ``--json``)."""
    rows = [r for t in trials for r in t["rows"]]
    keys = [*setup.GROUPS, *(f"chessboard {p}" for p in setup.CHESSBOARD)]
    table = []
    for key in keys:
        n_all = sum(1 for r in rows if key in (r["group"], r["experiment"]))
        entry: dict[str, Any] = {"experiment": key, "targets": n_all}
        for loop in LOOPS:
            entry[loop] = _cell(pooled(rows, key, loop), per_trial(rows, key, loop))
        entry["paper"] = PAPER_MM.get(key)
        table.append(entry)
    calib = {k: mean_ci([t[f"{k}_residual_mm"] for t in trials])._asdict()
             for k in ("handeye", "beam")}  # fmt: skip
    return {"experiments": table, "comparisons": comparisons(rows),
            "calibration_residual_mm": calib,
            "ik_time_s": _trial_mean_ci(rows, "ik_time_s", {"ok", "lost"}),
            "servo_iterations": _trial_mean_ci(rows, "servo_iterations", {"ok"}),
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
            data = [pooled(rows, k, loop) for k in keys]
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
