"""``beamrelay study all -o reports``: every study at paper scale, and ``reports/index.md``.

Order: ik-grid, calibration, sensitivity, mirror-sweep, coverage, experiments,
experiments-n2, online, moving-target. Each study runs its ``main`` at its paper-scale
``TRIALS``, writes into ``OUT/<name>/`` and its report is stamped with its provenance
(:mod:`planner.studies.provenance`); the index is built from those stamps alone: the commit,
seed, trials and wall time each report states, and whether they all come from one clean
commit with one set of packages.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import typer

from planner.studies import (
    calibration,
    common,
    coverage,
    experiments,
    experiments_n2,
    ik_grid,
    mirror_sweep,
    moving_target,
    online,
    sensitivity,
)
from planner.studies.provenance import stamp, write_index

STUDIES: dict[str, Any] = {
    "ik-grid": ik_grid,
    "calibration": calibration,
    "sensitivity": sensitivity,
    "mirror-sweep": mirror_sweep,
    "coverage": coverage,
    "experiments": experiments,
    "experiments-n2": experiments_n2,
    "online": online,
    "moving-target": moving_target,
}
"""The studies in the order they run (name -> module with ``main`` and ``TRIALS``)."""
ORDER = tuple(STUDIES)


#: what a study runs with beyond its scale and seed, as keyword arguments of its ``main`` and
#: as options of its command: the experiments with their error budget (one effect at a time)
OPTIONS: dict[str, tuple[dict[str, Any], str]] = {"experiments": ({"ablate": True}, " --ablate")}

#: the files a study writes (a study's folder holds nothing else)
OUTPUTS = (".md", ".csv", ".png", ".json")


def clear_outputs(folder: Path) -> None:
    """Delete the previous run's outputs in ``folder`` (files with a suffix in
    ``OUTPUTS``), so that every file left there after the run comes from it."""
    if folder.is_dir():
        for f in folder.iterdir():
            if f.is_file() and f.suffix in OUTPUTS:
                f.unlink()


def run_one(
    name: str, out: Path, seed: int, workers: int | None, scheduler: str | None
) -> dict[str, Any]:
    """Run one study at its paper scale in a folder cleared of its previous outputs and
    stamp its report; returns its figures."""
    mod = STUDIES[name]
    clear_outputs(out / name)
    t0 = time.perf_counter()
    kwargs, flags = OPTIONS.get(name, ({}, ""))
    figures = dict(mod.main(mod.TRIALS, seed, out / name, workers, scheduler, **kwargs))
    command = f"beamrelay study {name} --trials {mod.TRIALS} --seed {seed} -o {out / name}{flags}"
    stamp(out / name / "report.md", command, mod.TRIALS, seed, time.perf_counter() - t0)
    return figures


def main(
    trials: int, seed: int, out: Path, workers: int | None, sched: str | None
) -> dict[str, Any]:
    """Every study at its paper scale (--trials ignored), then OUT/index.md from the
    reports' provenance stamps."""
    common.out_dir(out)
    timings: dict[str, float] = {}
    for name in ORDER:
        typer.echo(f"== study {name}")
        t0 = time.perf_counter()
        run_one(name, out, seed, workers, sched)
        timings[name] = time.perf_counter() - t0
    write_index(out, ORDER)
    return {"study": "all", "seconds": timings}


command = common.study_command(main, 1, Path("reports"), report="index.md")
