"""Supervisor: restarts with doubling back-off, ordered stop, exit codes."""

from __future__ import annotations

import itertools
import signal
import sys
import time
from pathlib import Path

import pytest

from planner.service import supervisor as sv
from planner.service.supervisor import Supervisor
from tests.drivers.conftest import wait_for


@pytest.mark.serial
def test_restarts_crashing_child_with_backoff_and_stops(tmp_path: Path) -> None:
    crash = [sys.executable, "-c", "import sys; print('hi'); sys.exit(3)"]
    sleep = [sys.executable, "-c", "import time; time.sleep(60)"]
    sup = Supervisor({"crash": crash, "sleep": sleep}, tmp_path)
    sup.start()
    restarts_at: list[float] = []
    t0 = time.monotonic()
    while len(restarts_at) < 3 and time.monotonic() - t0 < 20:
        if "crash" in sup.poll():
            restarts_at.append(time.monotonic() - t0)
        time.sleep(0.01)
    assert sup.children["crash"].restarts == 3 and sup.children["crash"].last_exit == 3
    gaps = [b - a for a, b in itertools.pairwise(restarts_at)]
    # delays double from RESTART_DELAY: 0.5 s, 1 s, 2 s (plus the child's own run time)
    assert sv.RESTART_DELAY <= restarts_at[0] < sv.RESTART_DELAY + 1.5
    assert 2 * sv.RESTART_DELAY <= gaps[0] < 2 * sv.RESTART_DELAY + 1.5
    assert 4 * sv.RESTART_DELAY <= gaps[1] < 4 * sv.RESTART_DELAY + 1.5
    assert sup.children["sleep"].running and sup.children["sleep"].restarts == 0
    codes = sup.stop(timeout=5.0)
    assert codes["sleep"] == -signal.SIGTERM
    assert (tmp_path / "crash.log").read_text().count("hi") in (3, 4)  # 4th may be cut short


def test_kill_and_stop_escalates_to_sigkill(tmp_path: Path) -> None:
    stubborn = [
        sys.executable,
        "-c",
        "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
        "print('ready', flush=True); time.sleep(60)",
    ]
    sup = Supervisor({"stubborn": stubborn}, tmp_path)
    sup.start()
    wait_for(lambda: "ready" in (tmp_path / "stubborn.log").read_text(), 10.0, "child ready")
    t0 = time.monotonic()
    codes = sup.stop(timeout=0.5)
    assert codes["stubborn"] == -signal.SIGKILL
    assert 0.5 <= time.monotonic() - t0 < 3.0
    assert sup.poll() == []  # nothing restarts once stopping
