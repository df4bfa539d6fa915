"""Off when the driver dies: the real UR driver process (``beamrelay driver robot --backend
ur``) runs against the simulated controller of the test process (:func:`ur_fake.serve`),
opens the treatment gate inside a planned ``laser_on`` interval, and is SIGKILLed or
SIGSTOPped. Nothing of the driver runs any more: the controller's RTDE watchdog stops the
control script and the runstate action the driver configured at start-up drops the gate."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.robot.ur_fake import FakeURController, serve
from planner.bus.session import Keys
from tests.drivers.conftest import Heartbeats, raw_session, wait_for
from tests.drivers.robot.test_robot_node import smooth_move
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "s_curve.yaml"  # laser.gate: arm0, output 0
HOME = np.array([0, -1.5708, 1.5708, -1.5708, -1.5708, 0])
GATE = 0
WATCHDOG_HZ = 25.0  # --rtde-watchdog: the script stops 40 ms after the last command


ATTEMPTS = 3  # start-ups (a loaded machine may stall a start-up past the 40 ms watchdog)


def start(endpoint: str, keys: Keys, log: Path) -> tuple[FakeURController, Any, Any]:
    """A served controller and the driver process on it: (controller, halt, process)."""
    fake = FakeURController(HOME, lag=False)
    port, halt = serve(fake)
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    cmd = [sys.executable, "-m", "planner.cli", "driver", "robot", "--name", "arm0",
           "--backend", "ur", "--host", f"ur-fake:{port}", "--rtde-watchdog", str(WATCHDOG_HZ),
           "--scenario", str(SCENARIO), "--endpoint", endpoint, "--prefix", keys.prefix]  # fmt: skip
    return fake, halt, subprocess.Popen(cmd, stderr=log.open("wb"), env=env)


def gate_on(fake: FakeURController, client: Any, keys: Keys) -> bool:
    """Arm the watchdog, send a 4 s move with laser_on [0.2, 3.8] s; whether the gate is on
    0.3 s later with the control script running."""
    wait_for(lambda: fake.watchdog_hz == WATCHDOG_HZ, 60.0, "driver armed the RTDE watchdog")
    assert fake.runstate == {GATE: 1}  # configured by the driver: low when not running
    move = smooth_move(HOME, np.array([0, 0, 0, 0, 0, 0.2]), 4.0, id="A", session="P1")
    client.put(keys.trajectory("arm0"),
               move.model_copy(update={"laser_on": [[0.2, 3.8]]}).model_dump_json().encode())  # fmt: skip
    end = time.monotonic() + 10.0
    while fake.running and not fake.outputs >> GATE & 1 and time.monotonic() < end:
        time.sleep(0.005)
    time.sleep(0.3)
    return bool(fake.outputs >> GATE & 1) and fake.running and fake.watchdog_trips == 0


@pytest.mark.serial
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSTOP], ids=["SIGKILL", "SIGSTOP"])
def test_dead_or_hung_ur_driver_drops_the_gate_within_100_ms(
    hub: Any, endpoint: str, keys: Keys, sig: signal.Signals, tmp_path: Path
) -> None:
    client = raw_session(endpoint)
    token = client.liveliness().declare_token(keys.alive("planner"))
    beats = Heartbeats(client, keys.prefix, "P1")
    log = tmp_path / "driver.log"
    driver: Any = None
    halt: Any = None
    try:
        for attempt in range(1, ATTEMPTS + 1):
            fake, halt, driver = start(endpoint, keys, log)
            if gate_on(fake, client, keys):
                break
            print(f"attempt {attempt}: gate not on with the script running "
                  f"(watchdog trips {fake.watchdog_trips}): {log.read_text()[-300:]}")  # fmt: skip
            driver.kill()
            driver.wait(10)
            halt.set()
        else:
            raise AssertionError(f"no start-up with the gate on in {ATTEMPTS} attempts")
        killed = time.monotonic()
        driver.send_signal(sig)
        wait_for(lambda: not fake.outputs >> GATE & 1, 2.0, "gate output low")
        low = next(t for t, bits in fake.output_log if t > killed and not bits >> GATE & 1)
        ms = 1e3 * (low - killed)
        print(f"{sig.name}: gate output low {ms:.1f} ms after the signal "
              f"(RTDE watchdog {1e3 / WATCHDOG_HZ:.0f} ms)")  # fmt: skip
        assert not fake.running and fake.watchdog_trips == 1  # the watchdog, not the driver
        assert ms < 100.0
        # it was the watchdog, nothing sooner: the output dropped a watchdog period after the
        # driver's last write (its loop may have last written a few ms before the signal)
        silent = low - fake._last_write
        print(f"  {1e3 * silent:.1f} ms after the driver's last write")
        assert silent >= 1 / WATCHDOG_HZ - 1e-4
    finally:
        if driver is not None:
            if sig == signal.SIGSTOP:
                driver.send_signal(signal.SIGCONT)
            driver.kill()
            driver.wait(10)
        if halt is not None:
            halt.set()
        beats.stop()
        token.undeclare()
        client.close()
