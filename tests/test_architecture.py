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

import pytest

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
        f.write("\nfrom planner.service import node as _node  # noqa: E402\n")
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


def import_cycles(packages: tuple[str, ...]) -> list[tuple[str, ...]]:
    """Each import cycle among ``packages`` (importable from sys.path) as the shortest chain
    that closes it, once per cycle. Imports under ``if TYPE_CHECKING:`` do not run and do
    not count; function-local imports do."""
    import grimp

    graph = grimp.build_graph(*packages, exclude_type_checking_imports=True, cache_dir=None)
    cycles: dict[frozenset[str], tuple[str, ...]] = {}
    for module in sorted(graph.modules):
        for imported in sorted(graph.find_modules_directly_imported_by(module)):
            back = graph.find_shortest_chain(importer=imported, imported=module)
            if back is not None:
                cycles.setdefault(frozenset(back), (module, *back))
    return sorted(cycles.values())


def test_no_import_cycle() -> None:
    assert import_cycles(PACKAGES) == []


def test_an_import_cycle_is_found(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A three-module cycle, one link of it a function-local import, and a TYPE_CHECKING-only
    pair, in a throw-away package."""
    pkg = tmp_path / "cyclepkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from cyclepkg import b\n")
    (pkg / "b.py").write_text("def f():\n    from cyclepkg import c\n")
    (pkg / "c.py").write_text("import cyclepkg.a\n")
    (pkg / "d.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                              "    import cyclepkg.e\n")  # fmt: skip
    (pkg / "e.py").write_text("import cyclepkg.d\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    found = import_cycles(("cyclepkg",))
    assert len(found) == 1 and set(found[0]) == {"cyclepkg.a", "cyclepkg.b", "cyclepkg.c"}
    assert found[0][0] == found[0][-1]  # the chain closes
