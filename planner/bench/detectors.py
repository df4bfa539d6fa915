"""``beamrelay bench detectors``: the image-position noise of the drivers' real spot and
ChArUco detectors on rendered images (:mod:`planner.simcell.detector_noise`), per named
condition: per-axis RMS (px) with its 95 % CI, and what it is in mm across the line of sight
at the paper_n1 camera's distance and focal length. The conditions marked ``model`` are the
sources of :data:`planner.model.d435.SPOT_PX` and :data:`~planner.model.d435.CORNER_PX`.
Figures are printed, not asserted.
"""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer


def figures(spot_samples: int, corner_samples: int, seed: int) -> dict[str, dict[str, Any]]:
    """Every condition's figures: RMS and CI (px), samples, missed, points, mm at the paper_n1
    distance, and whether it is the model's condition."""
    from planner.simcell import detector_noise as dn

    mm_per_px = 1e3 * dn.DISTANCE_M / dn.PAPER_N1.fx
    out: dict[str, dict[str, Any]] = {}
    runs: list[tuple[str, Any, str]] = [
        *((n, lambda c=c: dn.measure_spot_px(c, spot_samples, seed), dn.SPOT_MODEL_CONDITION)
          for n, c in dn.SPOT_CONDITIONS.items()),
        *((n, lambda c=c: dn.measure_corner_px(c, corner_samples, seed), dn.CORNER_MODEL_CONDITION)
          for n, c in dn.CORNER_CONDITIONS.items()),
    ]  # fmt: skip
    for name, run, model in runs:
        m = run()
        out[name] = {
            "rms_px": m.rms_px, "ci95_px": list(m.ci95_px), "samples": m.samples,
            "missed": m.missed, "points": m.points, "rms_mm_at_distance": m.rms_px * mm_per_px,
            "model": name == model,
        }  # fmt: skip
    return out


def command(
    samples: Annotated[
        int, typer.Option("--samples", min=2, help="Spot samples per condition (boards: a fifth).")
    ] = 600,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    as_json: Annotated[
        bool, typer.Option("--json", help="One JSON object on the last line.")
    ] = False,
) -> None:
    """Spot-centroid and ChArUco-corner noise (px per image axis, 95 % CI) of the drivers'
    detectors on rendered frames: spot on a board, on skin, saturated, small after YUYV;
    corners at 0.6 and 0.9 m, sharp and blurred."""
    from planner.simcell.detector_noise import DISTANCE_M, PAPER_N1

    result = figures(samples, max(2, samples // 5), seed)
    typer.echo(f"per-axis RMS error of the detectors' pixel (paper_n1 camera, fx {PAPER_N1.fx:g}"
               f" px; mm across the line of sight at {DISTANCE_M:g} m), seed {seed}")  # fmt: skip
    for name, f in result.items():
        lo, hi = f["ci95_px"]
        typer.echo(
            f"{name:28s} {f['rms_px']:.4f} px [95 % CI {lo:.4f}, {hi:.4f}] ="
            f" {f['rms_mm_at_distance']:.3f} mm; {f['samples']} samples, {f['missed']}"
            f" missed, {f['points']} points{'  <- model' if f['model'] else ''}"
        )
    if as_json:
        typer.echo(json.dumps(result))
