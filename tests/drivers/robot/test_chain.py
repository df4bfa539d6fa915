"""The gate's driver and the other arms of the beam chain, on a simulated clock: arm0 (the
gate's driver, streamed a laser interval) watches arm1, played on the fake bus (token,
joint states at 250 Hz, status at 10 Hz and on every change). Every time is simulated."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from drivers.robot.chain import START_GRACE, STATE_TIMEOUT, ChainWatch
from drivers.robot.node import RobotNode
from tests.drivers.robot.fake_bus import FakeBus, SimClock
from tests.drivers.robot.test_streaming_node import DT, KEYS, LIMITS, Rig, wave

LASER = (0.5, 1.0)  # s of stream time: the laser interval
FAULT_AT = 0.7  # s: arm1 fails mid-interval


class ChainRig(Rig):
    """:class:`Rig` whose node (arm0, gate on output 0) has ``chain=("arm0", "arm1")``."""

    def __init__(self, arm1_token: bool = True) -> None:
        super().__init__()
        self.bus, self.clock = FakeBus(), SimClock()
        self.node = RobotNode(self.bus, KEYS, "arm0", self.sim, LIMITS, clock=self.clock,
                              gate_output=0, chain=("arm0", "arm1")).attach()  # fmt: skip
        self.bus.token(KEYS.alive("planner"))
        if arm1_token:
            self.bus.token(KEYS.alive("arm1"))
        self.arm1: dict[str, Any] = {"mode": "streaming", "protective_stop": False}
        self.arm1_states = True
        self._sent: dict[str, Any] = {}

    def period(self, n: int = 1) -> None:
        for _ in range(n):
            if self.arm1_states and self.k % 2 == 0:
                body = {"t": 0.0, "names": [], "q": [], "qd": []}
                self.bus.put(KEYS.joint_states("arm1"), json.dumps(body))
            if self.arm1 != self._sent or self.k % 50 == 0:
                body = {"schema": "beamrelay.status/1", "robot": "arm1", "t": 0.0, **self.arm1}
                self.bus.put(KEYS.status("arm1"), json.dumps(body))
                self._sent = dict(self.arm1)
            super().period()


def laser(t: float) -> bool:
    return LASER[0] <= t < LASER[1]


def stream_with(rig: ChainRig, fail: Any = None) -> None:
    """Stream the wave with the laser interval; ``fail(rig)`` at :data:`FAULT_AT`."""
    for k in range(round(1.5 / DT)):
        if fail is not None and k == round(FAULT_AT / DT):
            fail(rig)
        q, qd = wave(k * DT)
        rig.send(q, qd, laser(k * DT))
        rig.period()


def test_a_live_chain_lets_the_interval_play() -> None:
    rig = ChainRig()
    rig.period(3)
    stream_with(rig)
    lit = np.flatnonzero(rig.gate[3:])
    assert lit[0] == round(LASER[0] / DT) and lit[-1] == round(LASER[1] / DT) - 1
    assert KEYS.stop not in rig.bus.published


def _token_gone(rig: ChainRig) -> None:
    rig.bus.token(KEYS.alive("arm1"), alive=False)


def _states_stop(rig: ChainRig) -> None:
    rig.arm1_states = False


FAILURES = {
    "braking": (lambda rig: rig.arm1.update(mode="braking"), "arm1 is braking"),
    "protective stop": (lambda rig: rig.arm1.update(protective_stop=True), "protective-stopped"),
    "fault": (lambda rig: rig.arm1.update(mode="fault", fault="boom"), "arm1 is fault (boom)"),
    "idle": (lambda rig: rig.arm1.update(mode="idle"), "arm1 is idle"),
    "token gone": (_token_gone, "arm1's liveliness token is gone"),
    "hung": (_states_stop, "arm1's joint states: silent for"),
}


@pytest.mark.parametrize("failure", list(FAILURES))
def test_a_failing_chain_arm_switches_treatment_off_and_stops_every_arm(failure: str) -> None:
    fail, says = FAILURES[failure]
    rig = ChainRig()
    rig.period(3)
    stream_with(rig, fail)
    gate = np.array(rig.gate[3:])
    at = round(FAULT_AT / DT)
    assert gate[round(LASER[0] / DT) : at].all()  # on until the failure
    off = at + int(np.argmin(gate[at:]))  # first period off
    allowed = 1 if failure != "hung" else int(np.ceil(STATE_TIMEOUT / DT)) + 2
    print(f"{failure}: treatment off {1e3 * (off - at) * DT:.0f} ms (simulated) after it")
    assert 0 <= off - at <= allowed and not gate[off:].any()
    laser_reason = rig.bus.last(KEYS.laser)["reason"]
    assert "beam chain not live" in laser_reason and says in laser_reason
    stops = rig.bus.published[KEYS.stop]
    assert len(stops) == 1 and stops[0]["source"] == "arm0" and says in stops[0]["reason"]
    assert rig.modes[3 + off] in ("braking", "stopped")
    assert says in rig.status()["fault"]


@pytest.mark.parametrize("idle_for", [0.04, 0.3])
def test_a_chain_arm_may_start_a_little_after_this_one(idle_for: float) -> None:
    """Laser from the first setpoint on; arm1 still idle for ``idle_for`` s (its verdict
    comes later): within :data:`START_GRACE` nothing happens, later treatment goes off."""
    rig = ChainRig()
    rig.arm1["mode"] = "idle"
    rig.period(3)
    for k in range(round(0.5 / DT)):
        if k == round(idle_for / DT):
            rig.arm1["mode"] = "streaming"
        q, qd = wave(k * DT)
        rig.send(q, qd, True)
        rig.period()
    gate = np.array(rig.gate[3:])
    if idle_for < START_GRACE:
        assert gate[1:].all() and KEYS.stop not in rig.bus.published
    else:
        off = 1 + int(np.argmin(gate[1:]))
        assert abs(off * DT - START_GRACE) <= 2 * DT and not gate[off:].any()
        assert "arm1 is idle" in rig.bus.published[KEYS.stop][0]["reason"]


def test_an_arm_never_seen_blocks_the_interval() -> None:
    rig = ChainRig(arm1_token=False)
    rig.period(3)
    stream_with(rig)
    assert not any(rig.gate)
    assert "arm1's liveliness token is gone" in rig.bus.published[KEYS.stop][0]["reason"]


def test_chain_watch_reasons_in_order() -> None:
    clock = SimClock()
    watch = ChainWatch(("arm1", "arm2"), clock)
    assert watch.fault() == "arm1's liveliness token is gone"
    for r in ("arm1", "arm2"):
        watch.alive[r] = True
    assert watch.fault() == "arm1's joint states: none heard"
    for r in ("arm1", "arm2"):
        watch.state_at[r] = clock.t
    assert watch.fault() == "arm1: no status heard"
    clock.t += STATE_TIMEOUT + 0.001
    assert watch.fault() == "arm1's joint states: silent for 51 ms"


def test_a_driver_without_chain_subscribes_nothing_more() -> None:
    bus = FakeBus()
    rig = Rig()
    RobotNode(bus, KEYS, "arm0", rig.sim, LIMITS, gate_output=0).attach()
    assert KEYS.status("arm1") not in bus.subscribers and KEYS.stop in bus.subscribers
