"""Supervisor: restarts with doubling back-off (on a fake clock: exact delays), ordered stop,
exit codes."""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

from planner.service import supervisor as sv
from planner.service.supervisor import Supervisor
from tests.drivers.conftest import wait_for
from tests.fake_clock import FakeClock

CRASH = ["/bin/sh", "-c", "echo hi; exit 3"]
SLEEP = [sys.executable, "-c", "import time; time.sleep(60)"]


def crashed(sup: Supervisor, name: str = "crash") -> None:
    """Wait (real time) until child ``name`` has exited; the fake clock does not move."""
    proc = sup.children[name].proc
    assert proc is not None
    proc.wait(10)


def restart_delays(sup: Supervisor, clock: FakeClock, n: int) -> list[float]:
    """Let ``crash`` exit ``n`` times; each time the delay (s, on ``clock``) from the poll that
    notices the exit to the poll that restarts it, stepping the clock 1 ms at a time."""
    delays = []
    for _ in range(n):
        crashed(sup)
        noticed = clock()
        assert sup.poll() == []  # the exit is noticed now: the back-off starts
        while sup.poll() == []:
            clock.advance(0.001)
            assert clock() - noticed < 60.0
        delays.append(round(clock() - noticed, 9))
    return delays


def test_restarts_after_0_5_1_2_s_doubling_to_8_s(tmp_path: Path) -> None:
    clock = FakeClock(100.0)
    sup = Supervisor({"crash": CRASH, "sleep": SLEEP}, tmp_path, clock=clock)
    sup.start()
    try:
        delays = restart_delays(sup, clock, 6)
        assert delays == [0.5, 1.0, 2.0, 4.0, 8.0, 8.0]
        assert sv.RESTART_DELAY == 0.5 and sv.MAX_DELAY == 8.0
        assert sup.children["crash"].restarts == 6 and sup.children["crash"].last_exit == 3
        assert sup.children["sleep"].running and sup.children["sleep"].restarts == 0
        assert sup.uptime("sleep") == clock() - 100.0
        crashed(sup)  # the 7th run ends before the stop
    finally:
        codes = sup.stop(timeout=5.0)
    assert codes["sleep"] == -signal.SIGTERM
    assert (tmp_path / "crash.log").read_text().count("hi") == 7


def test_the_backoff_resets_after_a_stable_run(tmp_path: Path) -> None:
    clock = FakeClock(100.0)
    sup = Supervisor({"crash": CRASH}, tmp_path, clock=clock)
    sup.start()
    try:
        assert restart_delays(sup, clock, 3) == [0.5, 1.0, 2.0]
        clock.advance(sv.STABLE_AFTER + 0.001)  # the 4th run counts as stable when it ends
        assert restart_delays(sup, clock, 2) == [0.5, 1.0]
        clock.advance(sv.STABLE_AFTER)  # exactly STABLE_AFTER is not more than it
        assert restart_delays(sup, clock, 1) == [2.0]
    finally:
        sup.stop(timeout=5.0)


def test_a_manual_child_waits_for_the_operator_whatever_the_time(tmp_path: Path) -> None:
    clock = FakeClock(100.0)
    sup = Supervisor({"crash": CRASH}, tmp_path, manual=("crash",), clock=clock)
    sup.start()
    try:
        crashed(sup)
        for _ in range(3):
            assert sup.poll() == []
            clock.advance(100.0)
        child = sup.children["crash"]
        assert child.awaiting_operator and child.restarts == 0 and child.last_exit == 3
        assert sup.uptime("crash") == 0.0
        assert sup.restart("crash") and child.restarts == 1
    finally:
        sup.stop(timeout=5.0)


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


def test_a_childs_own_environment_reaches_only_it_and_survives_restarts(tmp_path: Path) -> None:
    show = ["/bin/sh", "-c", 'echo "token=${BR_TEST_TOKEN:-none} home=${HOME:+set}"']
    clock = FakeClock()
    sup = Supervisor({"console": show, "driver": show}, tmp_path, clock=clock,
                     env={"console": {"BR_TEST_TOKEN": "t0ken"}})  # fmt: skip
    sup.start()
    crashed(sup, "console")
    crashed(sup, "driver")
    sup.poll()  # the exits are noticed: the back-off starts
    clock.advance(5.0)
    assert "console" in sup.poll()  # it restarts, with the same environment
    crashed(sup, "console")
    sup.stop()
    console = (tmp_path / "console.log").read_text().split()
    assert console == ["token=t0ken", "home=set", "token=t0ken", "home=set"]
    assert (tmp_path / "driver.log").read_text().split()[:2] == ["token=none", "home=set"]
