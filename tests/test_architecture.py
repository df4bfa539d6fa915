"""The layer rule: import-linter's contracts (pyproject.toml) catch a bad import, and every
planner sub-package has a layer. That the contracts hold for the repository is checked by
``make test`` itself (``lint-imports``), not here again."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

from tests.paths import REPO

PACKAGES = ("planner", "schemas", "drivers")


def lint_imports(root: Path) -> subprocess.CompletedProcess[str]:
    """Run lint-imports on the packages under ``root`` with the repository's contracts."""
    code = "from importlinter.cli import lint_imports_command; lint_imports_command()"
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run(
        [sys.executable, "-c", code, "--no-cache", "--no-logo", str(REPO / "pyproject.toml")],
        capture_output=True, text=True, cwd=root, env=env, timeout=120,
    )  # fmt: skip


def test_an_upward_import_and_a_forbidden_one_are_caught(tmp_path: Path) -> None:
    for pkg in PACKAGES:
        shutil.copytree(REPO / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    with (tmp_path / "schemas/common.py").open("a") as f:
        f.write("\nfrom planner.service import bus as _bus  # noqa: E402\n")
    with (tmp_path / "planner/verify/metrics.py").open("a") as f:
        f.write("\nimport casadi as _casadi  # noqa: E402\n")
    proc = lint_imports(tmp_path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "schemas is not allowed to import planner.service" in proc.stdout
    assert "schemas.common -> planner.service" in proc.stdout
    assert "planner.verify is not allowed to import casadi" in proc.stdout


def test_every_planner_subpackage_has_a_layer() -> None:
    """A new sub-package or top-level module of ``planner`` must be placed in the layers."""
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers = next(c for c in config["contracts"] if c["type"] == "layers")["layers"]
    named = {
        name.strip().strip("()") for layer in layers for name in layer.replace(":", "|").split("|")
    }
    found = {
        f"planner.{p.stem if p.suffix == '.py' else p.name}"
        for p in (REPO / "planner").iterdir()
        if (p.suffix == ".py" and p.stem != "__init__") or (p / "__init__.py").is_file()
    }
    assert found - named == set(), f"not in the layers contract: {sorted(found - named)}"
