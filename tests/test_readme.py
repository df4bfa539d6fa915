"""The README's shell examples run as written on the simulated system and print the figures
the README quotes. Blocks marked ``<!-- readme-test: runs on the simulated system -->`` are
run line by line in a scratch folder (``scenarios`` linked in); ``beamrelay up`` runs in the
background on a free port until the block ends, and the ``request`` lines after it join
that bus. Lines that take minutes are left to the tests that own them (:data:`LEFT_OUT`)."""

from __future__ import annotations

import glob
import json
import os
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.drivers.conftest import free_port
from tests.paths import REPO

MARK = "<!-- readme-test: runs on the simulated system -->"
#: commands of the marked blocks not run here (minutes of work), and the tests that run them
LEFT_OUT = {
    "plan": "tests/planner/cli/test_cli_plan.py (1000 targets + plot: about a minute)",
    "check": "tests/planner/cli/test_cli_plan.py",
    "study": "tests/planner/studies",
    "bench": "tests/planner/bench",
}
CLI = [sys.executable, "-m", "planner.cli"]


def marked_blocks(text: str) -> list[list[str]]:
    """The command lines (comments and continuation lines joined) of every marked block."""
    blocks = re.findall(re.escape(MARK) + r"\n```sh\n(.*?)```", text, re.DOTALL)
    out = []
    for block in blocks:
        joined = block.replace("\\\n", " ")
        lines = [ln.split("  #")[0].strip() for ln in joined.splitlines()]
        out.append([ln for ln in lines if ln and not ln.startswith("#")])
    return out


def test_the_marked_blocks_are_the_tour_and_the_miscalibration_demo() -> None:
    blocks = marked_blocks((REPO / "README.md").read_text())
    assert len(blocks) == 2
    assert blocks[0][0].startswith("beamrelay validate") and "miscalibrated" in blocks[1][0]


def _argv(line: str, cwd: Path) -> list[str]:
    words = shlex.split(line.rstrip("&").strip())
    assert words[0] == "beamrelay", line
    args = []
    for w in words[1:]:
        if re.fullmatch(r"\[--[a-z-]+\]", w):  # an optional flag shown in brackets
            continue
        args += sorted(glob.glob(w, root_dir=cwd)) if "*" in w else [w]
    return CLI + args


def _run_block(lines: list[str], cwd: Path, env: dict[str, str]) -> dict[str, str]:
    """Run one block; the standard output of each request line, by line."""
    bus: list[str] = []
    up = None
    outputs = {}
    try:
        for line in lines:
            argv = _argv(line, cwd)
            command = argv[len(CLI)]
            if command in LEFT_OUT:
                continue
            if command == "up":
                bus = ["--endpoint", f"tcp/127.0.0.1:{free_port()}", "--prefix", "readme"]
                up = subprocess.Popen([*argv, *bus, "--no-live", "--duration", "300"], cwd=cwd,
                                      env=env, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL)  # fmt: skip
                continue
            extra = [*bus, "--timeout", "60"] if command == "request" else []
            proc = subprocess.run([*argv, *extra], cwd=cwd, env=env, capture_output=True,
                                  text=True, timeout=240)  # fmt: skip
            assert proc.returncode == 0, f"{line}\n{proc.stdout}\n{proc.stderr}"
            assert "Traceback" not in proc.stderr, line
            outputs[line] = proc.stdout + proc.stderr
    finally:
        if up is not None:
            up.send_signal(signal.SIGINT)
            up.wait(60)
    return outputs


def _measured_mm(output: str) -> float:
    found = re.search(r"measured spot error: median ([0-9.]+) mm", output)
    assert found, output
    return float(found.group(1))


@pytest.mark.serial  # the whole simulated system, twice
def test_readme_examples_run_as_written_and_print_the_quoted_figures(tmp_path: Path) -> None:
    (tmp_path / "scenarios").symlink_to(REPO / "scenarios")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    tour, demo = marked_blocks((REPO / "README.md").read_text())

    out = _run_block(tour, tmp_path, env)
    trace = next(v for k, v in out.items() if " trace " in k)
    assert "chain valid" in trace
    assert (tmp_path / "beam.yaml").is_file()  # the calibration the tour writes
    request = next(v for k, v in out.items() if " request " in k)
    assert _measured_mm(request) < 1.0 and "warning:" not in request  # a target on the board

    out = _run_block(demo, tmp_path, env)
    open_loop, closed = (v for k, v in out.items() if " request " in k)
    assert 4.5 < _measured_mm(open_loop) < 6.5  # README: "~5.5 mm from their targets"
    figures = json.loads(next(ln for ln in reversed(closed.splitlines()) if ln.startswith("{")))
    assert 4.5e-3 < figures["measured_error_before_median"] < 6.5e-3
    assert figures["measured_error_median"] < 3e-4  # README: "the scenario's 0.3 mm"
