"""``beamrelay serve / up / request``: user mistakes are one line and exit 2; no planner -> 1."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.drivers.conftest import free_port


def run(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "planner.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["request", "--points", "1,2"], "expected X,Y,Z (3 numbers), got 2"),
        (["request", "--points", "1,a,3"], "expected X,Y,Z numbers"),
        (["request", "--points", "1,2,3", "--frame", "base"], "expected world or camera"),
        (
            ["request", "--points", "1,2,3", "--normals", "0,0,1", "--normals", "0,1,0"],
            "2 given for 1",
        ),
        (["serve", "/nonexistent/scenario.yaml"], "scenario.yaml"),
        (["up", "/nonexistent/scenario.yaml", "--backend", "robotstudio"], "expected sim or ur"),
    ],
)
def test_user_mistakes_exit_2_with_one_line(args: list[str], words: str) -> None:
    out = run(*args)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], out.stderr


def test_request_without_planner_fails_in_time() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = run("request", "--points", "0,0,1", "--endpoint", endpoint, "--timeout", "1")
    assert out.returncode == 1
    assert "no reply from the planner on beamrelay/plan within 1 s" in out.stderr
