"""Every numbered example runs as a user would run it (a fresh interpreter) and prints what
its docstring promises; the figures are checked against their own definitions."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from tests.paths import REPO

EXAMPLES = sorted((REPO / "examples").glob("[0-9][0-9]_*.py"))


def run(path: object) -> str:
    out = subprocess.run(
        [sys.executable, str(path)], capture_output=True, text=True, timeout=300, cwd=REPO
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "Traceback" not in out.stderr
    return out.stdout


def test_examples_are_numbered_in_order() -> None:
    numbers = [int(p.name[:2]) for p in EXAMPLES]
    assert numbers == list(range(1, len(numbers) + 1)), [p.name for p in EXAMPLES]
    assert len(EXAMPLES) >= 5


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs(path: object) -> None:
    text = run(path)
    assert text.strip(), "an example prints what it did"
    errors_mm = [float(x) for x in re.findall(r"error ([0-9.e+-]+) mm", text)]
    if "02_" in str(path) or "05_" in str(path):
        assert errors_mm and max(errors_mm) < 1e-6  # exact in the model
    if "03_" in str(path):
        assert "violations" not in text and re.search(r"(\d+)/\1 targets solved", text)
    if "06_" in str(path):  # the registered model: its own 0.427 m upper arm, solved exactly
        assert "model ur5e_lab" in text and "[-0.8192 " in text  # -(0.427 + 0.3922) m
        assert errors_mm and max(errors_mm) < 1e-6
    if "04_" in str(path):
        assert errors_mm and max(errors_mm) < 5.0  # D435 noise, 20 poses: a few mm at most
