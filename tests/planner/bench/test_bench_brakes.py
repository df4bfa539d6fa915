"""``beamrelay bench brakes``: a short run of the whole simulated system under load, its
JSON figures (in-process, CliRunner)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from planner.bench.brakes import reclassify
from planner.cli.bench import app
from planner.errors import InputError


@pytest.mark.serial  # the whole simulated system plus CPU burners
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; -rR lists a rerun
@pytest.mark.timeout(120)
def test_bench_brakes_executes_under_load_and_counts() -> None:
    out = CliRunner().invoke(app, ["brakes", "--minutes", "0.15", "--load", "2", "--json"])
    assert out.exit_code == 0, out.output
    doc = json.loads(out.output.strip().splitlines()[-1])
    assert doc["executions"] >= 1 and doc["rejected"] == 0
    assert doc["false_brakes"] + doc["other_faults"] <= doc["executions"]
    hb = doc["heartbeat"]
    assert hb["beats"] > 500 and hb["gaps_over_100ms"] <= hb["gaps_over_50ms"]
    assert doc["load"] == 2 and doc["rt"] is True and "false brakes" in out.output
    fifo = os.geteuid() == 0
    assert any(("SCHED_FIFO 15" in b) is fifo for b in doc["priority"]), doc["priority"]


def test_bench_brakes_refuses_an_unbounded_load_in_one_line() -> None:
    out = CliRunner().invoke(app, ["brakes", "--load", "100"])
    assert isinstance(out.exception, InputError)  # the CLI prints it in one line, exit 2
    assert "--load must be in [0, 32], got 100" in str(out.exception)


def test_a_brake_the_planner_turned_into_a_stop_of_every_robot_counts_as_false(
    tmp_path: Path,
) -> None:
    """The driver brakes for a late beat, the planner then stops every robot and the
    execution's fault reads "stop requested": the planner's log names the brake."""
    log = tmp_path / "planner.log"
    log.write_text(
        "planning 4 targets\n"
        "stopping every robot: arm0 is braking during an execution: planner heartbeat lost: "
        "session abc silent for 101 ms\n"
        "stopping every robot: arm0 faulted: protective stop\n"
    )
    fig = {"false_brakes": 0, "other_faults": 2}
    reclassify(fig, log)
    assert fig == {"false_brakes": 1, "other_faults": 1}
    reclassify(fig, tmp_path / "missing.log")  # no log: counts stay
    assert fig == {"false_brakes": 1, "other_faults": 1}
