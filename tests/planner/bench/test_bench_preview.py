"""``beamrelay bench preview``: its JSON figures for a few runs, checked against what the test
measures itself (the command's wall time) and against each other (the whole request's CPU
time against the stage-by-stage pipeline's); a bad centre or run count is one line and
exit 2."""

from __future__ import annotations

import json
import time

from planner.service.handler import PREVIEW_RATE
from tests.cli_run import assert_usage_error, beamrelay

RUNS = 3


def test_preview_figures_of_the_k152_path() -> None:
    t0 = time.perf_counter()
    done = beamrelay("bench", "preview", "--runs", str(RUNS), "--json")
    elapsed_ms = 1e3 * (time.perf_counter() - t0)
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    # 150.6 mm at 1 mm: 152 samples, all solved to the NLP's precision, the trajectory timed
    assert doc["samples"] == doc["n_ok"] == 152 and doc["error_max_m"] < 1e-9
    assert 150.6e-3 / 0.02 < doc["duration_s"] < 150.6e-3 / 0.02 + 2.0
    stages = doc["stages"]
    assert set(stages) == {"path_solve", "verify", "beam_check", "timing", "document",
                           "json_encode"}  # fmt: skip
    for s in [doc["total"], doc["total_cpu"], *stages.values()]:
        assert 0.0 < s["median_ms"] <= s["p95_ms"] <= s["max_ms"], s
    # the timed runs happened inside the command: the slowest and the median of three runs
    # (two runs at least as long as the median) fit in the test's own clock
    assert doc["total"]["max_ms"] + (RUNS // 2) * doc["total"]["median_ms"] < elapsed_ms
    # the whole request and its stages run one by one do the same work: their CPU agrees
    staged = sum(s["median_ms"] for s in stages.values())
    assert 0.5 < staged / doc["total_cpu"]["median_ms"] < 2.0, (staged, doc["total_cpu"])
    # the laser is on for the marked path: ~ its duration at the preview rate, few measured
    # by coal
    rate = PREVIEW_RATE
    assert 0.9 * 150.6e-3 / 0.02 * rate < doc["beam_samples"] < doc["duration_s"] * rate
    assert 1 <= doc["beam_measured"] < doc["beam_samples"] / 10
    assert doc["bytes"] > 1e5
    # issue 26's goals for the console's click-to-preview: a 150-sample path, one target
    assert doc["goal_ms"] == 500.0 and doc["target_goal_ms"] == 200.0
    # the same path as the console sends it (camera frame): the same samples, all solved,
    # its path solve by stage
    cam = doc["camera"]
    assert cam["samples"] == cam["n_ok"] == doc["samples"]
    assert set(cam["stages"]) == {"first_sweep", "landing", "landed_sweep"}
    for s in [cam["total"], *cam["stages"].values()]:
        assert 0.0 < s["median_ms"] <= s["p95_ms"] <= s["max_ms"], s
    # one target: solved, and a fraction of the path's work
    t = doc["target"]
    assert doc["target_ok"] and 0.0 < t["median_ms"] <= t["p95_ms"] <= t["max_ms"], t
    assert t["median_ms"] < doc["total"]["median_ms"]


def test_bad_options_are_one_line() -> None:
    for args, needle in ((["--centre", "1,2"], "--centre"), (["--runs", "0"], "--runs"),
                         (["--centre", "a,b,c"], "--centre")):  # fmt: skip
        assert_usage_error(beamrelay("bench", "preview", *args), needle)
