"""STYLE's size limits (../shared/STYLE.md: no module over ~400 lines, no function over ~60),
held by the code or excused where they are not, each excuse one line with its reason:

- a function over 60 lines (def to its last line, signature and docstring included) has a
  comment ``# long: <why>`` on the line right above its ``def`` (or its first decorator);
- a module over 400 lines has a line ``# long module: <why>``.

An excuse on a function or module within its limit fails too, so the list stays true."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.paths import REPO

PACKAGES = ("planner", "schemas", "drivers")
MAX_FUNCTION, MAX_MODULE = 60, 400
FUNCTION_MARK, MODULE_MARK = "# long:", "# long module:"


def _sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py"))


def _excused(lines: list[str], node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
    above = lines[first - 2].strip() if first >= 2 else ""
    return above.startswith(FUNCTION_MARK) and len(above) > len(FUNCTION_MARK) + 3


def size_findings(path: Path, root: Path = REPO) -> list[str]:
    """What breaks the rule in one file: long and unexcused, or excused and not long."""
    text = path.read_text()
    lines = text.splitlines()
    name = path.relative_to(root)
    out = []
    long_module = len(lines) > MAX_MODULE
    marked = any(ln.startswith(MODULE_MARK) and len(ln) > len(MODULE_MARK) + 3 for ln in lines)
    if long_module != marked:
        why = "without" if long_module else "within the limit but with"
        out.append(f"{name}: {len(lines)} lines, {why} a '{MODULE_MARK} <why>' line")
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            n = (node.end_lineno or node.lineno) - node.lineno + 1
            if (n > MAX_FUNCTION) != _excused(lines, node):
                why = "without" if n > MAX_FUNCTION else "within the limit but with"
                out.append(f"{name}:{node.lineno} {node.name}: {n} lines, {why} '{FUNCTION_MARK}'")
    return out


def test_every_function_and_module_is_within_the_limits_or_says_why() -> None:
    findings = [f for p in _sources() for f in size_findings(p)]
    assert findings == [], "\n".join(findings)


def test_a_long_function_without_an_excuse_is_found(tmp_path: Path) -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION))
    src = tmp_path / "probe.py"
    src.write_text(f"def f():\n{body}\n\n\n# long: a probe\ndef g():\n    return 1\n")
    found = size_findings(src, tmp_path)
    assert len(found) == 2
    assert "f: 61 lines, without" in found[0] and "g: 2 lines, within the limit" in found[1]
