"""Every arm of the beam chain, or none: the N = 2 relay (``scenarios/n2_relay.yaml`` with
the laser gated by arm0's output 0 and a 0.4 s dwell) run by the planner and two simulated
arm drivers as real subprocesses. arm1 (the relay mirror, not the gate's arm) is SIGKILLed
(its token goes) or SIGSTOPped (a hung driver: its joint states stop) in the middle of the
laser's dwell: the gate's driver switches treatment off within 100 ms and ``<prefix>/stop``
is published, so arm0 brakes too."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from planner.service.client import RequestError, make_request
from tests.drivers.conftest import wait_for
from tests.paths import SCENARIOS
from tests.test_e2e import Bus

pytestmark = pytest.mark.timeout(240)

GATED = "  laser:\n    gate: {robot: arm0, output: 0}\n"
TARGETS = {"SIGKILL": [-0.88, 0.3, 0.05], "SIGSTOP": [-0.90, 0.27, 0.05]}  # on the grid
DWELL = 0.4  # s
KILL_AFTER = 0.15  # s into the dwell


def gated_relay() -> str:
    text = (SCENARIOS / "n2_relay.yaml").read_text()
    assert "  laser:\n" in text and "dwell: 0.0" in text
    return text.replace("  laser:\n", GATED, 1).replace("dwell: 0.0", f"dwell: {DWELL}")


class ChainBus(Bus):
    """:class:`tests.test_e2e.Bus` on the gated relay, without camera."""

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from planner.service.up import child_commands

        self.scenario.write_text(gated_relay())
        self.argv = child_commands(self.scenario, ["arm0", "arm1"], endpoint=self.endpoint,
                                   prefix=self.keys.prefix, camera=False)  # fmt: skip


@pytest.fixture(scope="module")
def chain(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ChainBus]:
    b = ChainBus(tmp_path_factory.mktemp("chain"))
    try:
        for name in ("planner", "arm0", "arm1"):
            b.start(name)
        yield b
    finally:
        b.close()


@pytest.mark.serial  # the whole simulated system, wall-clock latency
@pytest.mark.parametrize("how", ["SIGKILL", "SIGSTOP"])
def test_a_chain_arm_lost_mid_dwell_turns_the_laser_off_within_100ms(
    chain: ChainBus, how: str
) -> None:
    laser: list[tuple[float, dict[str, Any]]] = []  # (receive UNIX time, LaserState)
    stops: list[tuple[float, dict[str, Any]]] = []
    subs = [
        chain.hub.declare_subscriber(
            chain.keys.laser,
            lambda s: laser.append((time.time(), json.loads(s.payload.to_bytes()))),
        ),
        chain.hub.declare_subscriber(
            chain.keys.stop, lambda s: stops.append((time.time(), json.loads(s.payload.to_bytes())))
        ),
    ]

    replies: list[Any] = []

    def send() -> None:
        try:
            replies.append(chain.client.request(make_request([TARGETS[how]], execute=True), 30.0))
        except RequestError as exc:
            replies.append(exc)

    request = threading.Thread(target=send, daemon=True)
    arm1 = chain.procs["arm1"]
    try:
        request.start()

        def lit() -> list[float]:
            return [m["t"] for _, m in laser if m["on"] and m["robot"] == "arm0"]

        deadline = time.monotonic() + 60.0
        while not lit() and time.monotonic() < deadline:
            time.sleep(0.002)
        verdicts = [getattr(r, "args", r) if isinstance(r, Exception) else
                    (r.get("execution"), r.get("execution_reason")) for r in replies]  # fmt: skip
        assert lit(), f"the laser never came on: {verdicts}; stops: {stops}"
        time.sleep(max(0.0, lit()[0] + KILL_AFTER - time.time()))
        t_fail = time.time()
        os.kill(arm1.pid, getattr(signal, how))
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            off = [m for _, m in laser if not m["on"] and m["t"] >= lit()[0]]
            if off and stops:
                break
            time.sleep(0.002)
        time.sleep(0.3)
    finally:
        if arm1.poll() is None:  # stopped, or never killed (the test failed before)
            os.kill(arm1.pid, signal.SIGKILL)
        arm1.wait(10)
        for sub in subs:
            sub.undeclare()
        request.join(30)
        wait_for(lambda: "arm1" not in chain.alive, 15.0, "the dead arm1's token gone")
        chain.start("arm1")  # another test (or a rerun) needs it back
    on_at = lit()[0]
    off = [m for _, m in laser if not m["on"] and m["t"] >= on_at]
    assert off, "the laser stayed on"
    t_off = off[0]["t"]
    assert stops, "no stop published"
    t_stop, stop = stops[0]
    every = ", ".join(f"{m['source']} {1e3 * (t - t_fail):.1f} ms" for t, m in stops)
    print(
        f"{how} arm1 {1e3 * (t_fail - on_at):.0f} ms into the dwell: treatment off "
        f"{1e3 * (t_off - t_fail):.1f} ms after it ({off[0]['reason']}); stop from "
        f"{stop['source']} received {1e3 * (t_stop - t_fail):.1f} ms after it (all: "
        f"{every})"
    )
    assert t_fail - on_at < DWELL - 0.1, "the dwell ended before the failure: no evidence"
    # the gate's driver saw arm1 go, or the planner did first and published the stop
    why = off[0]["reason"]
    assert ("beam chain not live" in why and "arm1" in why) or "stop requested" in why, why
    assert t_off - t_fail < 0.100
    assert t_stop - t_fail < 0.150
