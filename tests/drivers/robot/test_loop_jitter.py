"""The 500 Hz control loop keeps its period while 8900-sample trajectories (3.6 MB each)
arrive at 10 Hz for 5 s over a real loopback bus: parsing runs in the worker process.
Parsing such a body in the Zenoh callback stalled the loop for 60-118 ms; the bound here
(30 ms) is generous because the machine is shared."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.bench import flood_jitter, loop_stats

pytestmark = pytest.mark.timeout(120)


def test_loop_stats_against_a_known_schedule() -> None:
    dt = 0.002
    starts = np.arange(1000) * dt
    starts[500:] += 0.010  # one period 10 ms late, everything after it shifted
    s = loop_stats(starts, dt)
    assert s.periods == 999
    assert s.p50_ms == pytest.approx(2.0)
    assert s.max_ms == pytest.approx(12.0)
    assert s.max_late_ms == pytest.approx(10.0)


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; a rerun is listed by -rR
def test_control_period_under_a_trajectory_flood() -> None:
    """One measurement: the parse stall was systematic (every checked body), so a single
    flood shows it; an unlucky scheduling hiccup of the shared machine gets the one rerun
    of the marker, listed in the log, not a silent second try here."""
    r = flood_jitter(seconds=5.0, samples=8900, rate=10.0, quiet=2.0)
    print(f"quiet: {r['quiet'].line()}")
    print(f"flood ({r['sent']} x {r['bytes'] / 1e6:.2f} MB, {r['checked']} checked, "
          f"{r['superseded']} superseded): {r['flood'].line()}")  # fmt: skip
    assert r["sent"] >= 45 and r["bytes"] > 3_000_000
    assert r["checked"] >= 3  # the flood really was parsed and checked
    assert r["checked"] + r["superseded"] == r["sent"]  # every body got its verdict
    assert r["flood"].periods > 2000  # ~500 Hz kept
    assert r["flood"].max_ms < 30.0, (
        f"max control period under the flood {r['flood'].max_ms:.1f} ms"
    )


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine
def test_ur_backend_bench_on_the_simulated_controller() -> None:
    """The UR backend under a (smaller) flood: the simulated controller's RTDE watchdog
    (10 Hz) never trips, every period writes the command register, ~500 Hz kept."""
    r = flood_jitter(seconds=2.0, samples=4000, rate=5.0, quiet=1.0, backend="ur")
    print(f"ur quiet: {r['quiet'].line()}\nur flood: {r['flood'].line()}")
    assert r["backend"] == "ur" and r["watchdog_trips"] == 0
    assert r["checked"] + r["superseded"] == r["sent"] >= 8
    assert r["flood"].periods > 800 and r["flood"].p50_ms == pytest.approx(2.0, abs=0.1)
