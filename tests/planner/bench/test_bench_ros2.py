"""``bench ros2``: the period figures, and bad input as one line with exit 2."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from planner.bench.ros2 import arrival_figures


def test_period_figures_of_known_arrivals() -> None:
    dt = np.array([0.004, 0.004, 0.006, 0.002, 0.004])
    f = arrival_figures(list(np.concatenate([[10.0], 10.0 + np.cumsum(dt)])))
    assert f["rate_hz"] == pytest.approx(1 / dt.mean())
    assert f["period_median_ms"] == pytest.approx(4.0)
    assert f["jitter_std_ms"] == pytest.approx(1e3 * dt.std())
    assert f["period_max_ms"] == pytest.approx(6.0)
    with pytest.raises(RuntimeError, match="only 2 samples"):
        arrival_figures([0.0, 1.0])


def test_bad_seconds_is_one_line_exit_2() -> None:
    out = subprocess.run([sys.executable, "-m", "planner.cli", "bench", "ros2", "--seconds", "0"],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert out.returncode == 2
    assert out.stderr.strip() == "error: --seconds 0: expected 0.5-600 s"
