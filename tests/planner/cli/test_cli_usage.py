"""Usage errors of every command: one line on stderr, exit status 2, never a traceback. The
command tree is walked, so a new command is covered without touching this file. The errors
run in-process through ``planner.cli.main`` (``tests.cli_run``); what only a real process
shows (no-args help, ``--version``, a typo, a closed stdout, ``plan | head``) runs as one."""

from __future__ import annotations

import enum
import os
import subprocess
import sys
import tomllib
import typing
from pathlib import Path
from typing import Any

import pytest
import typer.main

from planner.cli import app
from tests.cli_run import assert_usage_error, beamrelay
from tests.paths import REPO


def run(*args: str) -> subprocess.CompletedProcess[str]:
    """``beamrelay ARGS...`` in a fresh interpreter, as a user's shell starts it."""
    return subprocess.run(
        [sys.executable, "-m", "planner.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO,
    )


def walk(cmd: Any, path: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    out = [(path, cmd)]
    for name, sub in sorted((getattr(cmd, "commands", None) or {}).items()):
        out += walk(sub, (*path, name))
    return out


TREE = walk(typer.main.get_command(app))
GROUPS = [(p, c) for p, c in TREE if getattr(c, "commands", None)]
LEAVES = [(p, c) for p, c in TREE if not getattr(c, "commands", None)]


def ids(items: list[tuple[tuple[str, ...], Any]]) -> list[str]:
    return [" ".join(p) or "beamrelay" for p, _ in items]


def value_kind(param: Any) -> type | None:
    """int, float or Enum for a parameter that parses a value; None otherwise (typer with its
    own vendored click describes the annotation, plain click a ParamType)."""
    annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    if annotation is None:
        name = getattr(getattr(param, "type", None), "name", "")
        return {"integer": int, "float": float, "choice": enum.Enum}.get(name)
    inner = [a for a in typing.get_args(annotation) if a is not type(None)]
    if len(inner) == 1:  # X | None
        annotation = inner[0]
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return enum.Enum
    return annotation if annotation in (int, float) else None


def options(cmd: Any) -> list[Any]:
    return [p for p in cmd.params if p.param_type_name == "option" and not p.is_flag]


def test_tree_is_complete() -> None:
    names = {" ".join(p) for p, _ in TREE}
    for expected in ("plan", "calibrate beam", "study ik-grid", "bench ik", "driver robot", "up"):
        assert expected in names


@pytest.mark.parametrize(("path", "cmd"), GROUPS, ids=ids(GROUPS))
def test_group_unknown_command(path: tuple[str, ...], cmd: Any) -> None:
    first = sorted(cmd.commands)[0]
    typo = first[:-1] + ("x" if first[-1] != "x" else "y")
    assert_usage_error(beamrelay(*path, typo), "No such command", repr(typo))


@pytest.mark.parametrize(("path", "cmd"), TREE, ids=ids(TREE))
def test_unknown_option(path: tuple[str, ...], cmd: Any) -> None:
    assert_usage_error(beamrelay(*path, "--bogus"), "--bogus", "--help")


REQUIRED = [(p, c) for p, c in LEAVES if any(q.required for q in c.params)]


@pytest.mark.parametrize(("path", "cmd"), REQUIRED, ids=ids(REQUIRED))
def test_missing_argument(path: tuple[str, ...], cmd: Any) -> None:
    assert_usage_error(beamrelay(*path), "Missing")


TYPED = [(p, c, o) for p, c in LEAVES for o in options(c) if value_kind(o) is not None]


@pytest.mark.parametrize(
    ("path", "cmd", "opt"), TYPED, ids=[f"{' '.join(p)} {o.opts[-1]}" for p, _, o in TYPED]
)
def test_bad_value(path: tuple[str, ...], cmd: Any, opt: Any) -> None:
    assert_usage_error(beamrelay(*path, opt.opts[-1], "twelve"), opt.opts[-1])


RANGED = [(p, c, o) for p, c, o in TYPED if getattr(o, "min", None) is not None]


@pytest.mark.parametrize(
    ("path", "cmd", "opt"), RANGED, ids=[f"{' '.join(p)} {o.opts[-1]}" for p, _, o in RANGED]
)
def test_below_minimum(path: tuple[str, ...], cmd: Any, opt: Any) -> None:
    assert_usage_error(beamrelay(*path, opt.opts[-1], str(opt.min - 1)), opt.opts[-1])


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["study", "ik-grid", "--trials", "0"], "--trials"),
        (["study", "ik-grid", "--trials", "1", "--seed", "-1", "-o", "{tmp}"], "--seed"),
        (["study", "ik-grid", "--workers", "-2"], "--workers"),
        (["up", "scenarios/paper_n1.yaml", "--duration", "-1"], "--duration"),
        (["request", "--points", "0,0,0", "--timeout", "0"], "--timeout"),
        (["request", "--points", "0,0,0", "--timeout", "nan"], "--timeout"),
        (["bench", "service", "--n-single", "-1"], "--n-single"),
        (["bench", "path", "--sizes", "-5"], "--sizes"),
        (["bench", "path", "--sizes", "100,1"], "--sizes"),
    ],
)
def test_out_of_range_counts_and_times(args: list[str], named: str, tmp_path: Path) -> None:
    assert_usage_error(beamrelay(*[a.replace("{tmp}", str(tmp_path)) for a in args]), named)


def test_no_arguments_prints_help() -> None:
    proc = run()
    assert proc.returncode == 0, proc.stderr
    assert "Usage: beamrelay" in proc.stdout and "plan" in proc.stdout and not proc.stderr


def test_version() -> None:
    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"beamrelay {version}", proc


def test_suggestion_for_a_typo() -> None:
    assert_usage_error(run("plna"), "No such command 'plna'", "Did you mean 'plan'")


@pytest.mark.parametrize(
    "args", [["--help"], ["validate", "scenarios/paper_n1.yaml", "scenarios/n2_relay.yaml"]]
)
def test_closed_stdout_is_not_an_error(args: list[str]) -> None:
    """``beamrelay ... | head``: the reader went away before we wrote a byte."""
    read, write = os.pipe()
    os.close(read)
    proc = subprocess.run(
        [sys.executable, "-m", "planner.cli", *args],
        stdout=write,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    os.close(write)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


def test_plan_into_head(tmp_path: Path) -> None:
    shell = (
        f"{sys.executable} -m planner.cli plan scenarios/paper_n1.yaml -o {tmp_path}/p.json "
        "| head -c 1 >/dev/null; echo status=${PIPESTATUS[0]}"
    )
    proc = subprocess.run(
        ["bash", "-c", shell], capture_output=True, text=True, cwd=REPO, timeout=300
    )
    assert "status=0" in proc.stdout and "Traceback" not in proc.stderr, proc.stderr
    assert (tmp_path / "p.json").is_file()


# the help of these commands lives in other modules that still cite the internal spec
SPEC_IN_OTHER_MODULES = {("serve",), ("plan",), ()}


@pytest.mark.parametrize(("path", "cmd"), TREE, ids=ids(TREE))
def test_help_cites_no_internal_document(path: tuple[str, ...], cmd: Any) -> None:
    from typer.testing import CliRunner

    result = CliRunner().invoke(app, [*path, "--help"], prog_name="beamrelay")
    assert result.exit_code == 0
    if path not in SPEC_IN_OTHER_MODULES:
        assert "SPEC" not in result.output
