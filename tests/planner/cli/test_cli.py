"""The command line: every area registered, ``--help`` light, exit statuses."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from tests import cli_run
from tests.paths import REPO

ROOT = REPO
HEAVY = ("casadi", "pinocchio", "open3d", "pyrealsense2", "rtde_control", "matplotlib", "zenoh")


def test_help_imports_no_heavy_module() -> None:
    code = "import sys, planner.cli; print(__import__('json').dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = {m.split(".")[0] for m in json.loads(out.stdout)}
    assert not loaded & set(HEAVY), f"imported at --help: {sorted(loaded & set(HEAVY))}"


def test_every_command_is_registered() -> None:
    from planner.cli import app

    result = CliRunner().invoke(app, ["--help"])
    assert result.exit_code == 0
    for name in ("validate", "trace", "plan", "check", "calibrate", "study", "bench", "serve"):
        assert name in result.output
    for name in ("driver", "up", "request"):
        assert name in result.output
    studies = CliRunner().invoke(app, ["study", "--help"]).output
    for name in (
        "ik-grid",
        "calibration",
        "sensitivity",
        "mirror-sweep",
        "coverage",
        "experiments",
    ):
        assert name in studies
    assert "online" in studies
    benches = CliRunner().invoke(app, ["bench", "--help"]).output
    for name in ("ik", "path", "service"):
        assert name in benches


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["trace", "nope.yaml"], "nope.yaml"),
        (["plan", "nope.yaml", "-o", "x.json"], "nope.yaml"),
        (["check", "nope.json"], "nope.json"),
    ],
)
def test_missing_files_exit_2_with_one_line(args: list[str], words: str) -> None:
    cli_run.assert_usage_error(cli_run.beamrelay(*args), words)


def test_invalid_trace_is_exit_1() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "planner.cli", "trace", str(ROOT / "scenarios/paper_n1.yaml"), "--q",
         "arm0=0,-1.5,1.5,-1.5,1.5,0"],
        capture_output=True,
        text=True,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "NOT valid" in proc.stdout


def test_the_command_tree_is_exactly_the_registered_one() -> None:
    import typer.main

    from planner.cli import app

    root = typer.main.get_command(app)
    assert sorted(root.commands) == sorted(  # type: ignore[attr-defined]
        ["validate", "trace", "plan", "check", "serve", "up", "request", "calibrate", "study",
         "bench", "driver", "record", "replay", "robot", "hw", "console", "ros2"]
    )  # fmt: skip
    groups = root.commands  # type: ignore[attr-defined]
    assert sorted(groups["ros2"].commands) == ["bridge"]
    assert sorted(groups["calibrate"].commands) == [
        "beam",
        "collect",
        "handeye",
        "rollback",
        "simulate",
    ]
    assert sorted(groups["study"].commands) == sorted(
        [
            "ik-grid",
            "calibration",
            "sensitivity",
            "mirror-sweep",
            "coverage",
            "experiments",
            "experiments-n2",
            "online",
            "moving-target",
            "all",
            "index",
        ]
    )
    assert sorted(groups["bench"].commands) == [
        "brakes",
        "camera",
        "corners",
        "detectors",
        "ik",
        "marking",
        "path",
        "plan",
        "preview",
        "ros2",
        "safety",
        "service",
        "servo",
        "track",
    ]


@pytest.mark.parametrize("module", ["planner.studies.coverage", "planner.bench.safety",
                                    "planner.cli.node", "planner.cli.driver"])  # fmt: skip
def test_a_missing_command_module_fails_loudly(module: str) -> None:
    """A module that cannot be imported (misspelt, deleted, broken) stops the CLI with the
    module's name instead of quietly dropping its commands from ``--help``."""
    code = (
        f"import sys; sys.modules[{module!r}] = None\n"
        "from planner.cli import main\n"
        "main(['--help'])\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode != 0, proc.stdout
    assert "ModuleNotFoundError" in proc.stderr and module in proc.stderr
