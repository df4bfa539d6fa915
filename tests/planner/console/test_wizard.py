"""The calibration wizard's steps: the commands it runs, its inputs, the report it shows."""

from __future__ import annotations

import sys
import time
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
    assert calibrate_argv("beam", S, D, O) == [
        *CLI, "calibrate", "beam", "/d.json", "--scenario", "/s.yaml", "-o", "/c.yaml"]  # fmt: skip


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: collect_argv("laser", S, D, 12, None, []), "unknown calibration"),
        (lambda: collect_argv("handeye", S, D, 2, None, []), "poses 2"),
        (lambda: collect_argv("beam", S, D, 12, None, []), "board centre"),
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
