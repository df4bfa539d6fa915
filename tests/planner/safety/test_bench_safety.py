"""The safety benchmark runs as a module and reports consistent figures."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from planner.bench.safety import GAP, bench_system
from tests.cli_run import assert_usage_error, beamrelay


def test_bench_systems_have_neighbours_at_the_gap():
    for n in (2, 3):
        s = bench_system(n)
        P = np.array([r.world_T_base[:3, 3] for r in s.robots])
        d = np.linalg.norm(P - np.roll(P, 1, axis=0), axis=1)
        np.testing.assert_allclose(d, GAP, atol=1e-12)


def test_module_prints_json_figures():
    out = subprocess.run(
        [sys.executable, "-m", "planner.bench.safety", "--robots", "1,2", "--seconds", "0.01",
         "--ik-targets", "20", "--no-plan", "--json"],
        capture_output=True, text=True, check=True, timeout=300,
    )  # fmt: skip
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    rows = doc["rows"]
    assert doc["ik"]["targets"] == 20 and doc["ik"]["ik_median_on_us"] > 0
    assert doc["ik"]["ik_ratio"] == pytest.approx(
        doc["ik"]["ik_median_on_us"] / doc["ik"]["ik_median_off_us"]
    )
    assert "plan" not in doc
    assert [r["n_robots"] for r in rows] == [1, 2]
    # 13 parts per UR5e (11 capsules, mirror, mount): arm-arm pairs alone are 13^2 for N = 2
    assert rows[1]["pairs"] - 2 * rows[0]["pairs"] == 13**2
    assert all(r["distance_queries_per_s"] > 0 for r in rows)


def test_module_rejects_bad_robot_counts():
    out = subprocess.run(
        [sys.executable, "-m", "planner.bench.safety", "--robots", "two"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2
    assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_bench_safety_is_a_beamrelay_bench_command():
    out = beamrelay("bench", "safety", "--robots", "1", "--seconds", "0.01", "--ik-targets", "-3",
                    "--no-plan")  # fmt: skip
    assert_usage_error(out, "--ik-targets")
