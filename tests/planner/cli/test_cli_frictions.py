"""First-hour frictions of the command line: units on --q, readable evidence, check figures
that agree with their verdict, help text without ``<bool>`` on flags."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.paths import REPO


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *args], capture_output=True,
                          text=True, cwd=REPO)  # fmt: skip


def test_trace_refuses_joint_values_in_degrees_with_one_line() -> None:
    proc = _cli("trace", "scenarios/paper_n1.yaml", "--q", "arm0=0,-90,90,-90,-90,0")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr
    assert "degrees" in proc.stderr and "joint 1 = -90 rad" in proc.stderr
    assert f"{np.radians(-90):.4f} rad" in proc.stderr  # the conversion, -1.5708


def test_check_radians_accepts_values_inside_the_limits() -> None:
    from planner.cli.core import check_radians
    from planner.errors import InputError

    lower, upper = np.full(6, -2 * np.pi), np.full(6, 2 * np.pi)
    check_radians("arm0", np.radians([0, -90, 90, -90, -90, 0]), lower, upper)
    with pytest.raises(InputError, match="outside its limits") as info:
        check_radians("arm0", np.array([0, 0, 4.0, 0, 0, 0]), lower, np.full(6, 3.0))
    assert "degrees" not in str(info.value)  # 4 rad is beyond the limit, not degrees


def test_evidence_is_one_readable_line_with_four_significant_digits() -> None:
    from planner.model.status import evidence_text

    evidence = {"q": [0.1] * 6, "occluded": {"segment": "arm0->target", "object": "board",
                "point": np.array([0.12345678901234567, -0.5, 1e-9]), "distance": 0.0123456789}}  # fmt: skip
    text = evidence_text(evidence)
    assert text == ("occluded={segment=arm0->target, object=board, point=[0.1235 -0.5 1e-09], "
                    "distance=0.01235}")  # fmt: skip


def test_check_figures_over_the_limit_say_they_are_within_the_allowance() -> None:
    from planner.cli.plan import _figure_text
    from planner.verify.tolerances import RATE_SLACK

    over = _figure_text("jerk_max_ratio", 1.001)
    assert over.startswith("jerk max 100.1 % of limit") and f"{100 * RATE_SLACK:g} %" in over
    assert _figure_text("velocity_max_ratio", 0.5) == "velocity max 50.0 % of limit"


def test_no_help_text_shows_a_type_on_a_flag() -> None:
    """Every command's help (click's formatter: flags without ``<bool>``, paragraphs
    re-wrapped to the width instead of keeping the docstring's line breaks)."""
    from typer.testing import CliRunner

    from planner.cli import app
    from tests.planner.cli.test_cli_usage import TREE

    for path, _ in TREE:
        result = CliRunner().invoke(app, [*path, "--help"], prog_name="beamrelay",
                                    terminal_width=100)  # fmt: skip
        assert result.exit_code == 0, path
        assert "<bool>" not in result.output and "╭" not in result.output, path
        assert max(len(line) for line in result.output.splitlines()) <= 100, path
    text = CliRunner().invoke(app, ["request", "--help"], terminal_width=100).output
    assert re.search(r"^ +--execute +Move the robots\.$", text, re.MULTILINE), text
    assert "(closed loop) a target did not converge" in " ".join(text.split())


def test_a_beam_result_never_overwrites_the_hand_eye_file(tmp_path: Path) -> None:
    from planner.cli.calibrate import _write
    from planner.errors import InputError

    out = tmp_path / "calibration.yaml"
    held = "system: {camera: {world_T_camera: {xyz: [1, 2, 3]}}}\nreport: {kind: handeye}\n"
    out.write_text(held)
    with pytest.raises(InputError, match=r"holds the handeye calibration.*-o beam\.yaml"):
        _write({"system": {}, "report": {"kind": "beam"}}, out)
    assert out.read_text() == held


def test_calibrate_writes_the_two_kinds_to_two_files_by_default() -> None:
    import inspect

    from planner.cli.calibrate import beam, handeye

    defaults = {f.__name__: inspect.signature(f).parameters["out"].default for f in (handeye, beam)}
    assert defaults == {"handeye": Path("handeye.yaml"), "beam": Path("beam.yaml")}
