"""``bench detectors`` in-process: every condition's figures, the model's two marked; a
misspelt option is one line and exit 2."""

from __future__ import annotations

import json

from planner.simcell import detector_noise as dn
from tests import cli_run


def test_bench_prints_every_condition_and_marks_the_models() -> None:
    ran = cli_run.beamrelay("bench", "detectors", "--samples", "10", "--seed", "1", "--json")
    assert ran.returncode == 0, ran.stderr
    figures = json.loads(ran.stdout.strip().splitlines()[-1])
    assert list(figures) == [*dn.SPOT_CONDITIONS, *dn.CORNER_CONDITIONS]
    assert [n for n, f in figures.items() if f["model"]] == [
        dn.SPOT_MODEL_CONDITION,
        dn.CORNER_MODEL_CONDITION,
    ]
    mm_per_px = 1e3 * dn.DISTANCE_M / dn.PAPER_N1.fx
    for name, f in figures.items():
        lo, hi = f["ci95_px"]
        assert 0 <= lo <= f["rms_px"] <= hi, name
        assert f["rms_mm_at_distance"] == f["rms_px"] * mm_per_px
        assert f["samples"] == (10 if name in dn.SPOT_CONDITIONS else 2)
        assert f"{name}" in ran.stdout and f"{f['rms_px']:.4f} px" in ran.stdout


def test_a_misspelt_option_is_one_line_and_exit_2() -> None:
    cli_run.assert_usage_error(cli_run.beamrelay("bench", "detectors", "--sample", "3"), "--sample")
    cli_run.assert_usage_error(
        cli_run.beamrelay("bench", "detectors", "--samples", "1"), "--samples"
    )
