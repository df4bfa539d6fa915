"""``beamrelay bench plan``: runs small grids end to end in child processes, reports every
stage; bad arguments are one line and exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from planner.bench.plan import grid_shape
from tests import cli_run


def beamrelay(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *args], capture_output=True,
                          text=True, timeout=600)  # fmt: skip


def test_grid_shapes() -> None:
    for n in (1000, 10_000, 100_000):
        a, b, c = grid_shape(n)
        assert a * b * c == n
    assert grid_shape(8) == (2, 2, 2)


def test_small_grids_every_stage() -> None:
    done = beamrelay("bench", "plan", "--sizes", "8,27", "--json")
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["bench"] == "plan"
    rows = out["rows"]
    assert [r["targets"] for r in rows] == [8, 27]
    for r in rows:
        assert "error" not in r
        assert r["solved"] == r["targets"] and r["check_violations"] == 0
        for stage in ("ik", "verify", "order", "timing", "document", "check"):
            assert r[f"{stage}_s"] > 0 and r[f"{stage}_peak_rss_mb"] >= r["start_rss_mb"] > 0
        assert r["duration_s"] <= r["duration_given_order_s"] * 1.02
        assert r["samples"] == pytest.approx(r["duration_s"] * 500 + 1, abs=1)
        assert r["plan_json_mb"] > 0


@pytest.mark.parametrize("args", [["--sizes", "0"], ["--sizes", "1e3"],
                                  ["--stages", "ik,bogus"], ["--scenario", "missing.yaml"]])  # fmt: skip
def test_bad_arguments_exit_2(args: list[str]) -> None:
    cli_run.assert_usage_error(cli_run.beamrelay("bench", "plan", *args))
