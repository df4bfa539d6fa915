"""``beamrelay plan`` / ``check`` end to end through the CLI entry point (exit statuses)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.cli import main
from tests import cli_run
from tests.planner.plan.test_pipeline import CURVE, SCENARIO, write_scenario
from tests.planner.verify.test_check import ramp_trajectory


def run(args: list[str]) -> int:
    with pytest.raises(SystemExit) as exc:
        main(args)
        raise SystemExit(0)
    return int(exc.value.code or 0)


def test_plan_then_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, png = tmp_path / "plan.json", tmp_path / "plan.png"
    assert run(["plan", str(write_scenario(tmp_path)), "-o", str(out), "--plot", str(png)]) == 0
    doc = json.loads(out.read_text())
    assert doc["metrics"]["n_ok"] == 18
    assert png.stat().st_size > 10_000
    text = capsys.readouterr().out
    assert "solved" in text and "18" in text
    assert run(["check", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert figures["violations"] == 0 and figures["spot.error_max_m"] <= 1e-12
    doc["solutions"][0]["q"]["arm0"][4] += 1e-3
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    assert run(["check", str(bad)]) == 1


def test_unsolved_target_exits_1_and_still_writes(tmp_path: Path) -> None:
    text = SCENARIO.replace(
        "grid: {center: [0.3, 0.3, 0.3], size: [0.1, 0.1, 0.1], n: [3, 3, 2]}",
        "points: [[0.3, 0.3, 0.3], [-3.0, -0.4, 0.3]]",
    )
    out = tmp_path / "plan.json"
    assert run(["plan", str(write_scenario(tmp_path, text)), "-o", str(out)]) == 1
    doc = json.loads(out.read_text())
    assert [s["reason"] for s in doc["solutions"]] == [None, "back_face"]


def test_bad_inputs_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["plan", str(tmp_path / "missing.yaml"), "-o", str(tmp_path / "p.json")]) == 2
    junk = tmp_path / "junk.json"
    junk.write_text("{not json")
    assert run(["check", str(junk)]) == 2
    junk.write_text(json.dumps({"schema": "beamrelay.plan/1"}))
    assert run(["check", str(junk)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 3


def test_path_plan_check_and_profiles(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, png = tmp_path / "c.json", tmp_path / "c.png"
    assert run(["plan", str(CURVE), "-o", str(out), "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    for words in ("on the path (s)", "max spot deviation (mm)", "max joint speed", "slowdowns"):
        assert words in text
    assert png.stat().st_size > 10_000
    assert (tmp_path / "c_profiles.png").stat().st_size > 30_000
    doc = json.loads(out.read_text())
    assert run(["check", str(out), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert figures["violations"] == 0
    assert figures["trajectory spot.path_deviation_max_m"] <= 5e-5
    dev = doc["metrics"]["extra"]["path_deviation_max"]
    assert f"{1e3 * dev:.4f}" in text  # the printed figure is the plan's
    # the sweep at 20 mm/s over the path length, within 10 %
    length = doc["metrics"]["extra"]["path_length"]
    assert figures["trajectory spot.path_duration_s"] == pytest.approx(length / 0.02, rel=0.1)


def test_check_exits_1_on_a_too_fast_trajectory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "plan.json"
    assert run(["plan", str(write_scenario(tmp_path)), "-o", str(out)]) == 0
    fast = tmp_path / "fast.json"
    fast.write_text(json.dumps(ramp_trajectory(json.loads(out.read_text()), 1.2 * np.pi)))
    capsys.readouterr()
    assert run(["check", str(fast), "--json"]) == 1
    text = capsys.readouterr().out
    assert "velocity" in text and "120.0% of limit" in text
    figures = json.loads(text.strip().splitlines()[-1])
    assert figures["violations"] >= 1  # also: the ramp reaches no target, metrics.duration
    assert figures["trajectory limits.velocity_max_ratio"] == pytest.approx(1.2, rel=1e-9)


def test_failure_table_shows_reason_and_evidence() -> None:
    import numpy as np
    from rich.console import Console

    from planner.cli.plan import _failures
    from planner.ik import Solution

    ok = Solution("ok", None, np.zeros(6), np.zeros(3), 0.0, None, None, 0.0, 0, "closed_form", 0.0)
    bad = Solution(
        "failed", "occluded", None, None, float("inf"), None, None, 0.0, 0, "closed_form", 0.0,
        {"segment": "arm0->target", "distance_m": 0.123456, "point": np.array([1.0, 2.0, 3.0]),
         "q": [0.0] * 6},
    )  # fmt: skip
    console = Console(width=200, record=True)
    console.print(_failures([ok, bad, bad]))
    text = console.export_text()
    assert "first 2 of 2" in text
    assert "occluded" in text and "segment=arm0->target" in text
    assert "distance_m=0.1235" in text and "point=[1 2 3]" in text
    assert "q=" not in text


def beamrelay(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=600)  # fmt: skip


@pytest.fixture(scope="module")
def written_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("p")
    out = tmp / "plan.json"
    done = beamrelay("plan", write_scenario(tmp), "-o", out)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "check of the plan: OK" in done.stdout
    return out


def _zero_qd(doc: dict) -> None:  # type: ignore[type-arg]
    doc["trajectory"]["qd"]["arm0"] = np.zeros_like(doc["trajectory"]["qd"]["arm0"]).tolist()


def _drop_trajectory(doc: dict) -> None:  # type: ignore[type-arg]
    del doc["trajectory"]


def _edit_n_ok(doc: dict) -> None:  # type: ignore[type-arg]
    doc["metrics"]["n_ok"] = 17


@pytest.mark.parametrize(
    ("tamper", "words"),
    [(_zero_qd, "declared qd on joint"), (_drop_trajectory, "no trajectory"),
     (_edit_n_ok, "metrics.n_ok is 17, the plan gives 18")],
)  # fmt: skip
def test_check_catches_a_tampered_plan(written_plan: Path, tmp_path: Path, tamper: Any,
                                       words: str) -> None:  # fmt: skip
    doc = json.loads(written_plan.read_text())
    tamper(doc)
    bad = tmp_path / "tampered.json"
    bad.write_text(json.dumps(doc))
    done = beamrelay("check", bad)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert words in " ".join(done.stdout.split())
    assert beamrelay("check", written_plan).returncode == 0


def test_plan_and_check_print_lengths_in_mm(written_plan: Path) -> None:
    done = beamrelay("check", written_plan)
    text = " ".join(done.stdout.split())
    assert "error max" in text and " mm" in text
    assert "_m " not in text and "error_max_m" not in text  # SI names only in --json
    figures = json.loads(beamrelay("check", written_plan, "--json").stdout.splitlines()[-1])
    assert figures["spot.error_max_m"] <= 1e-12  # the JSON figures stay SI


def test_unsupported_plot_extension_is_refused_before_planning(tmp_path: Path) -> None:
    out = tmp_path / "plan.json"
    done = cli_run.beamrelay("plan", write_scenario(tmp_path), "-o", out, "--plot",
                             tmp_path / "x.xyz")  # fmt: skip
    cli_run.assert_usage_error(done, "--plot", ".png")
    assert not out.exists()  # refused up front: nothing planned, nothing written
    done = cli_run.beamrelay("plan", write_scenario(tmp_path), "-o", out, "--plot",
                             tmp_path / "missing" / "x.png")  # fmt: skip
    cli_run.assert_usage_error(done)
    assert not out.exists()


def test_help_texts_cite_no_spec_sections() -> None:
    for cmd in ("plan", "check"):
        done = cli_run.beamrelay(cmd, "--help")
        assert done.returncode == 0
        assert "SPEC" not in done.stdout and "section" not in done.stdout.lower()


def _short_row(doc: dict) -> None:  # type: ignore[type-arg]
    doc["trajectory"]["q"]["arm0"][3] = doc["trajectory"]["q"]["arm0"][3][:5]


def _narrow_table(doc: dict) -> None:  # type: ignore[type-arg]
    doc["trajectory"]["qdd"]["arm0"] = [row[:5] for row in doc["trajectory"]["qdd"]["arm0"]]


def _nan_rate(doc: dict) -> None:  # type: ignore[type-arg]
    doc["trajectory"]["qd"]["arm0"][7][2] = float("nan")


def _time_back(doc: dict) -> None:  # type: ignore[type-arg]
    t = doc["trajectory"]["t"]
    t[9], t[10] = t[10], t[9]


def _one_row_less(doc: dict) -> None:  # type: ignore[type-arg]
    del doc["trajectory"]["qd"]["arm0"][-1]


def _other_robot(doc: dict) -> None:  # type: ignore[type-arg]
    doc["trajectory"]["qdd"]["arm1"] = doc["trajectory"]["qdd"].pop("arm0")


def _strings(doc: dict) -> None:  # type: ignore[type-arg]
    doc["trajectory"]["t"] = [str(x) for x in doc["trajectory"]["t"]]


@pytest.mark.parametrize(
    ("tamper", "where", "words"),
    [(_short_row, "trajectory.q.arm0[3]", "expected 6 numbers, got 5"),
     (_narrow_table, "trajectory.qdd.arm0[0]", "expected 6 numbers, got 5"),
     (_nan_rate, "trajectory.qd.arm0[7][2]", "expected a finite number, got nan"),
     (_time_back, "trajectory.t[10]", "times must not decrease"),
     (_one_row_less, "trajectory.qd.arm0", "rows (one per t)"),
     (_other_robot, "trajectory.qdd", "differ from q's"),
     (_strings, "trajectory.t", "expected numbers")],
)  # fmt: skip
def test_check_refuses_a_malformed_trajectory_table(written_plan: Path, tmp_path: Path,
                                                    tamper: Any, where: str, words: str) -> None:  # fmt: skip
    """The dense tables are validated with numpy (not the model): a stranger's malformed
    table is one located line, exit 2, as any schema error is."""
    doc = json.loads(written_plan.read_text())
    tamper(doc)
    bad = tmp_path / "malformed.json"
    bad.write_text(json.dumps(doc))
    cli_run.assert_usage_error(cli_run.beamrelay("check", bad), where, words)
