"""Online calibration end to end, as a lab would run it: ``beamrelay up
scenarios/online_calibration.yaml --online-calibration FILE`` (planner, simulated camera and
arm as real processes; the cell's ``truth:`` is 0.4 deg and 3 mm off the planner's model),
``beamrelay request --execute`` on targets on the board and on the block in turn, then
``beamrelay calibrate rollback FILE``. Checked: the refit is accepted from the camera's own
rest spots on the two surfaces, the next open-loop request lands closer (the measured spot
error falls), the planner's log has one line per refit with its figures, and a rollback
is installed by the running planner and logged."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from planner.io.scenario import load_scenario
from planner.service.online_file import history, read_document, version_of
from tests.drivers.conftest import free_port
from tests.paths import REPO

pytestmark = [pytest.mark.serial, pytest.mark.timeout(300)]

SCENARIO = REPO / "scenarios" / "online_calibration.yaml"
CLI = [sys.executable, "-m", "planner.cli"]


def _request(bus: list[str], points: list[list[float]], env: dict[str, str]) -> dict:
    args = [a for p in points for a in ("--points", ",".join(f"{v:g}" for v in p))]
    proc = subprocess.run([*CLI, "request", *args, "--execute", "--dwell", "0.5", "--json",
                           *bus, "--timeout", "60"], capture_output=True, text=True,
                          timeout=200, env=env)  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _wait_version(path: Path, above: int, timeout: float) -> int:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.is_file():
            v = version_of(read_document(path))
            if v > above:
                return v
        time.sleep(0.2)
    raise AssertionError(f"no version above {above} in {path} within {timeout} s")


def _wait_for_line(path: Path, text: str, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.is_file() and text in path.read_text():
            return
        time.sleep(0.1)
    raise AssertionError(f"{text!r} not in {path} within {timeout} s")


def test_refits_from_rest_spots_on_two_surfaces_land_closer_and_roll_back(tmp_path: Path) -> None:
    points = [list(map(float, p)) for p in load_scenario(SCENARIO).model.targets.points]
    out = tmp_path / "online.yaml"
    logs = tmp_path / "logs"
    bus = ["--endpoint", f"tcp/127.0.0.1:{free_port()}", "--prefix", "onlinee2e"]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    up = subprocess.Popen([*CLI, "up", str(SCENARIO), "--online-calibration", str(out),
                           "--log-dir", str(logs), "--no-live", "--duration", "240", *bus],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)  # fmt: skip
    try:
        first = _request(bus, points, env)  # 12 rest spots, 6 on each surface
        version = _wait_version(out, 0, 60)
        again = _request(bus, points[:4], env)
        before = first["measured_error_median"]
        after = again["measured_error_median"]
        assert before > 2e-3, first  # 0.4 deg and 3 mm off: millimetres open loop
        assert after < 0.5 * before, (before, after)
        doc = read_document(out)
        surfaces = doc["report"]["online"]["surfaces"]
        assert set(surfaces) == {"board", "block"}, surfaces
        assert all(s["holdout_median_m"] < s["previous_median_m"] for s in surfaces.values())
        assert doc["report"]["online"]["mirror_margin_m"] > 0

        ran = subprocess.run([*CLI, "calibrate", "rollback", str(out), "--to", "0"],
                             capture_output=True, text=True, timeout=60, env=env)  # fmt: skip
        assert ran.returncode == 0, ran.stderr
        said = re.search(r"version (\d+) = version 0 \(was (\d+)\)", ran.stdout)
        assert said, ran.stdout
        new, was = int(said[1]), int(said[2])
        assert new > was >= version and new in history(out)
        _wait_for_line(logs / "planner.log",
                       f"calibration_rolled_back version={new} to=0 was={was}", 10)  # fmt: skip
        back = _request(bus, points[:2], env)
        print(f"measured spot error, median: {1e3 * before:.2f} mm open loop on version 0,"
              f" {1e3 * after:.3f} mm on version {version} (refit from {len(points)} rest"
              f" spots on board and block), {1e3 * back['measured_error_median']:.2f} mm after"
              f" the rollback to version 0 (as version {new})")  # fmt: skip
        assert back["measured_error_median"] > 0.5 * before  # the nominal model again
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(60)
    planner_log = (logs / "planner.log").read_text()
    refits = [ln for ln in planner_log.splitlines() if " refit_" in ln]
    assert any("refit_accepted" in ln and "surface.block=" in ln for ln in refits), refits
    assert any("refit_refused" in ln and "at least 7" in ln for ln in refits), refits
