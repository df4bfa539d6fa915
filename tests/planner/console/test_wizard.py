"""The calibration wizard's steps: the commands it runs, its inputs, the report it shows."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from planner.console.wizard import (
    StepRunner,
    bus_options,
    calibrate_argv,
    collect_argv,
    parse_aim,
    report_markdown,
)
from planner.errors import InputError
from tests.paths import REPO

S, D, O = Path("/s.yaml"), Path("/d.json"), Path("/c.yaml")
CLI = [sys.executable, "-m", "planner.cli"]


def test_collect_and_calibrate_run_the_projects_commands_with_the_bus() -> None:
    bus = bus_options("tcp/127.0.0.1:9", "p", Path("/z.json5"))
    assert bus == ["--endpoint", "tcp/127.0.0.1:9", "--prefix", "p", "--zenoh-config", "/z.json5"]
    assert bus_options(None, "beamrelay", None) == []
    assert collect_argv("handeye", S, D, 12, None, bus) == [
        *CLI, "calibrate", "collect", "handeye", "--scenario", "/s.yaml", "-o", "/d.json",
        "--poses", "12", *bus]  # fmt: skip
    beam = collect_argv("beam", S, D, 16, [-0.492, -0.55, -0.06], [])
    assert beam[-2:] == ["--aim", "-0.492,-0.55,-0.06"]
    fast = collect_argv("handeye", S, D, 3, None, [], speed=1.0)
    assert fast[fast.index("--speed") + 1] == "1"
    assert calibrate_argv("beam", S, D, O) == [
        *CLI, "calibrate", "beam", "/d.json", "--scenario", "/s.yaml", "-o", "/c.yaml"]  # fmt: skip


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: collect_argv("laser", S, D, 12, None, []), "unknown calibration"),
        (lambda: collect_argv("handeye", S, D, 2, None, []), "poses 2"),
        (lambda: collect_argv("beam", S, D, 12, None, []), "board centre"),
        (lambda: collect_argv("handeye", S, D, 12, None, [], speed=1.5), "1.5 rad/s"),
        (lambda: parse_aim("1,2"), "3 numbers"),
        (lambda: parse_aim("1,a,2"), "numbers"),
        (lambda: parse_aim("1,nan,2"), "3 numbers"),
        (lambda: parse_aim("1,2,1e9"), "100 m"),
    ],
)
def test_bad_inputs_are_input_errors(call: object, match: str) -> None:
    with pytest.raises(InputError, match=match):
        call()  # type: ignore[operator]


def test_the_report_shows_residuals_and_deviations(tmp_path: Path) -> None:
    f = tmp_path / "c.yaml"
    f.write_text("system: {}\nreport:\n  residual_mean: 0.0011\n  std: {x: 1.0e-4}\n")
    text = report_markdown(f)
    assert (
        f"wrote {f}" in text
        and "residual_mean: `0.0011`" in text
        and "std: `{'x': 0.0001}`" in text
    )


def test_one_step_at_a_time_and_its_output_is_shown() -> None:
    shown: list[str] = []
    codes: list[int] = []
    runner = StepRunner(shown.append)
    runner.run([sys.executable, "-c", "import time; print('a'); print('b'); time.sleep(0.5)"],
               codes.append)  # fmt: skip
    with pytest.raises(InputError, match="still running"):
        runner.run([sys.executable, "-c", "pass"])
    end = time.monotonic() + 30
    while not codes and time.monotonic() < end:
        time.sleep(0.05)
    assert codes == [0] and shown[-1].split() == ["a", "b"]


def wait_until(pred: Callable[[], object], timeout: float, what: str) -> float:
    """Seconds until ``pred()`` held; fails after ``timeout`` s."""
    t0 = time.monotonic()
    while not pred():
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(0.02)
    return time.monotonic() - t0


def gone(pid: int) -> bool:
    """The process ``pid`` has exited (no such process, or a zombie not yet reaped)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


#: a step that says it started and then runs for a minute
SLEEPER = "import time; print('started', flush=True); time.sleep(60)"
#: the same, deaf to SIGTERM
DEAF = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); " + SLEEPER[12:]


@pytest.mark.parametrize(("code", "signum"), [(SLEEPER, signal.SIGTERM), (DEAF, signal.SIGKILL)])
def test_closing_ends_the_running_step(code: str, signum: int) -> None:
    """A step that ends on SIGTERM ends at once; one that ignores it is killed after the
    wait; no step starts after the close."""
    shown: list[str] = []
    runner = StepRunner(shown.append)
    runner.run([sys.executable, "-c", code])
    wait_until(lambda: shown and "started" in shown[-1], 30.0, "the step's first line")
    assert runner.proc is not None
    pid = runner.proc.pid
    t0 = time.monotonic()
    code_ = runner.close(timeout=1.0)
    took = time.monotonic() - t0
    print(f"\nstep pid {pid} ({signal.Signals(signum).name}) ended {took:.2f} s after close()")
    assert code_ == -signum and gone(pid)
    assert took < (0.8 if signum == signal.SIGTERM else 1.0 + 0.8)
    with pytest.raises(InputError, match="closing"):
        runner.run([sys.executable, "-c", "pass"])


def test_a_step_outlives_the_thread_that_started_it() -> None:
    """Linux sends the parent-death signal when the thread that forked the child ends:
    viser runs a button's callback on a worker thread, and the step must survive it."""
    shown: list[str] = []
    runner = StepRunner(shown.append)
    starter = threading.Thread(target=runner.run, args=([sys.executable, "-c", SLEEPER],))
    starter.start()
    starter.join()
    wait_until(lambda: shown and "started" in shown[-1], 30.0, "the step's first line")
    time.sleep(0.5)
    try:
        assert runner.running
    finally:
        runner.close()


#: a console stand-in: starts a step, prints the step's pid once the step is asleep (silent:
#: a step that writes after its parent died would end on the broken pipe), waits to be killed
PARENT = f"""
import sys, threading, time
from planner.console.wizard import StepRunner
asleep = threading.Event()
r = StepRunner(lambda text: asleep.set() if "started" in text else None)
r.run([sys.executable, "-c", {SLEEPER!r}])
asleep.wait(30)
print(r.proc.pid, flush=True)
time.sleep(120)
"""


def test_a_step_ends_when_the_console_process_is_killed() -> None:
    """SIGKILL leaves the console no chance to clean up: the kernel's parent-death signal
    (SIGTERM) ends the step."""
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True,
                              cwd=REPO)  # fmt: skip
    try:
        assert parent.stdout is not None
        pid = int(parent.stdout.readline())
        assert not gone(pid)
        parent.kill()
        parent.wait(10)
        took = wait_until(lambda: gone(pid), 5.0, f"step {pid} to end after its parent's SIGKILL")
        print(f"\nstep pid {pid} ended {took:.3f} s after its parent was killed")
    finally:
        parent.kill()
        parent.wait()
