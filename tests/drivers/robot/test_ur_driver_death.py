"""Off when the driver dies: the real UR driver process (``beamrelay driver robot --backend
ur``) runs against the simulated controller of the test process (:func:`ur_fake.serve`),
opens the treatment gate inside a planned ``laser_on`` interval, and is SIGKILLed or
SIGSTOPped. Nothing of the driver runs any more: the controller's RTDE watchdog stops the
control script and the runstate action the driver configured at start-up drops the gate."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from typing import Any

import numpy as np
import pytest

from drivers.robot.ur_fake import CYCLE, FakeURController, serve
from planner.service.bus import Keys
from tests.drivers.conftest import Heartbeats, raw_session, wait_for
from tests.drivers.robot.test_robot_node import smooth_move
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "s_curve.yaml"  # laser.gate: arm0, output 0
HOME = np.array([0, -1.5708, 1.5708, -1.5708, -1.5708, 0])
GATE = 0
WATCHDOG_HZ = 25.0  # --rtde-watchdog: the script stops 40 ms after the last command


@pytest.mark.serial
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSTOP], ids=["SIGKILL", "SIGSTOP"])
def test_dead_or_hung_ur_driver_drops_the_gate_within_100_ms(
    hub: Any, endpoint: str, keys: Keys, sig: signal.Signals
) -> None:
    fake = FakeURController(HOME, lag=False)
    port, halt = serve(fake)
    client = raw_session(endpoint)
    token = client.liveliness().declare_token(keys.alive("planner"))
    beats = Heartbeats(client, keys.prefix, "P1")
    laser: list[dict[str, Any]] = []
    sub = client.declare_subscriber(
        keys.laser, lambda s: laser.append(json.loads(s.payload.to_bytes()))
    )
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    cmd = [sys.executable, "-m", "planner.cli", "driver", "robot", "--name", "arm0",
           "--backend", "ur", "--host", f"ur-fake:{port}", "--rtde-watchdog", str(WATCHDOG_HZ),
           "--scenario", str(SCENARIO), "--endpoint", endpoint, "--prefix", keys.prefix]  # fmt: skip
    driver = subprocess.Popen(cmd, stderr=subprocess.PIPE, env=env)
    try:
        wait_for(lambda: fake.watchdog_hz == WATCHDOG_HZ, 60.0, "driver armed the RTDE watchdog")
        assert fake.runstate == {GATE: 1}  # configured by the driver: low when not running
        move = smooth_move(HOME, np.array([0, 0, 0, 0, 0, 0.2]), 4.0, id="A", session="P1")
        client.put(keys.trajectory("arm0"),
                   move.model_copy(update={"laser_on": [[0.2, 3.8]]}).model_dump_json().encode())  # fmt: skip
        wait_for(lambda: fake.outputs >> GATE & 1 == 1, 10.0, "treatment gate on")
        time.sleep(0.3)
        assert fake.outputs >> GATE & 1 and fake.running
        killed = time.monotonic()
        driver.send_signal(sig)
        wait_for(lambda: not fake.outputs >> GATE & 1, 2.0, "gate output low")
        low = next(t for t, bits in fake.output_log if t > killed and not bits >> GATE & 1)
        ms = 1e3 * (low - killed)
        print(f"{sig.name}: gate output low {ms:.1f} ms after the signal "
              f"(RTDE watchdog {1e3 / WATCHDOG_HZ:.0f} ms)")  # fmt: skip
        assert not fake.running and fake.watchdog_trips == 1  # the watchdog, not the driver
        assert ms < 100.0
        assert ms > 1e3 / WATCHDOG_HZ - 2 * CYCLE * 1e3  # it was the watchdog, nothing sooner
    finally:
        if sig == signal.SIGSTOP:
            driver.send_signal(signal.SIGCONT)
        driver.kill()
        driver.wait(10)
        beats.stop()
        sub.undeclare()
        token.undeclare()
        client.close()
        halt.set()
