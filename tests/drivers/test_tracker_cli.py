"""``beamrelay driver tracker`` as users start it: TargetStream at its rate on a real bus,
late by its latency; mistakes are one line, exit 2; ``up`` starts it for moving targets."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from planner.bus.session import Keys, decode
from planner.io.scenario import load_scenario
from planner.service.up import child_commands, has_tracked_targets
from schemas.messages import TargetStream
from tests import cli_run
from tests.drivers.conftest import wait_for
from tests.paths import SCENARIOS

CLI = [sys.executable, "-m", "planner.cli", "driver", "tracker"]
BREATHING = SCENARIOS / "breathing.yaml"


def run(args: list[str], endpoint: str, prefix: str, scenario: Path = BREATHING) -> Any:
    bus = ["--scenario", str(scenario), "--endpoint", endpoint, "--prefix", prefix]
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    return subprocess.Popen([*CLI, *args, *bus], stderr=subprocess.PIPE, env=env)


def test_tracker_publishes_the_moving_targets_late_by_its_latency(
    hub: Any, endpoint: str, keys: Keys
) -> None:
    got: list[tuple[float, Any]] = []
    sub = hub.declare_subscriber(keys.target_stream, lambda s: got.append((time.time(), s)))
    proc = run(["--seed", "1", "--latency", "0.02"], endpoint, keys.prefix)
    try:
        wait_for(lambda: len(got) >= 30, timeout=40, what="30 tracker frames")
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=20)
        sub.undeclare()
    assert proc.returncode == 0
    msgs = [(t, decode(s.payload.to_bytes(), TargetStream)) for t, s in got]
    assert {m.id for _, m in msgs} == {"phantom"}
    assert all(len(m.points) == 3 and m.normals is not None for _, m in msgs)
    assert all(arrived - m.t >= 0.02 for arrived, m in msgs)  # sent after the capture + latency
    z = np.array([m.points[0][2] for _, m in msgs])
    expected = -0.06 + 0.005 * np.sin(2 * np.pi * 0.25 * np.array([m.t for _, m in msgs]))
    assert np.abs(z - expected).max() < 2e-3  # the breathing sine, within the marker noise


def test_tracker_mistakes_exit_2_with_one_line(endpoint: str) -> None:
    for args, needle, scenario in [
        (["--latency", "0.05"], "--latency", BREATHING),
        (["--rate", "0"], "--rate", BREATHING),
        ([], "no targets.points lie on a scene object with a motion", SCENARIOS / "paper_n1.yaml"),
    ]:
        bus = ["--scenario", scenario, "--endpoint", endpoint, "--prefix", "trbad"]
        cli_run.assert_usage_error(cli_run.beamrelay("driver", "tracker", *args, *bus), needle)


def test_up_starts_the_tracker_only_for_tracked_moving_targets() -> None:
    assert has_tracked_targets(load_scenario(BREATHING))
    assert not has_tracked_targets(load_scenario(SCENARIOS / "paper_n1.yaml"))
    argv = child_commands(BREATHING, ["arm0"], endpoint="tcp/127.0.0.1:7447", tracker=True)
    assert argv["tracker"][3:6] == ["driver", "tracker", "--scenario"]
    real = child_commands(BREATHING, ["arm0"], backend="ur", endpoint="tcp/127.0.0.1:7447",
                          tracker=True)  # fmt: skip
    assert "tracker" not in real  # a real system has a real tracker
