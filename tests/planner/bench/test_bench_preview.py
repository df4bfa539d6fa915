"""``beamrelay bench preview``: its JSON figures for one run (child process); a bad centre
or run count is one line and exit 2."""

from __future__ import annotations

import json

from tests.planner.bench.test_bench_marking import beamrelay


def test_preview_figures_of_the_k152_path() -> None:
    done = beamrelay("bench", "preview", "--runs", "1", "--json")
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    # 150.6 mm at 1 mm: 152 samples, all solved to the NLP's precision, the trajectory timed
    assert doc["samples"] == doc["n_ok"] == 152 and doc["error_max_m"] < 1e-9
    assert 150.6e-3 / 0.02 < doc["duration_s"] < 150.6e-3 / 0.02 + 2.0
    stages = doc["stages"]
    assert set(stages) == {"path_solve", "verify", "beam_check", "timing", "document",
                           "json_encode"}  # fmt: skip
    assert all(0.0 <= s["median_ms"] <= s["p95_ms"] <= s["max_ms"] for s in stages.values())
    # the laser is on for the marked path: ~ its duration at 500 Hz, few measured by coal
    assert 0.9 * 150.6e-3 / 0.02 * 500 < doc["beam_samples"] < doc["duration_s"] * 500
    assert 1 <= doc["beam_measured"] < doc["beam_samples"] / 10
    assert doc["bytes"] > 1e5 and doc["goal_met"] is (doc["total"]["median_ms"] < 200.0)


def test_bad_options_are_one_line() -> None:
    for args, needle in ((["--centre", "1,2"], "--centre"), (["--runs", "0"], "--runs"),
                         (["--centre", "a,b,c"], "--centre")):  # fmt: skip
        out = beamrelay("bench", "preview", *args)
        assert out.returncode == 2, out.stdout + out.stderr
        assert needle in out.stderr and "Traceback" not in out.stderr
        assert len(out.stderr.strip().splitlines()) == 1
