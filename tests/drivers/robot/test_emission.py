"""The emission supervisor in the gate's driver (:mod:`drivers.robot.gate`), on a simulated
clock: whatever trajectory it is sent, the treatment output obeys ``laser.limits``, goes off
and aborts the motion when the speed fraction drops inside an interval, and a read-back
mismatch is a latched fault. The aiming beam has its own output. Times are simulated."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from drivers.robot.follower import Reference
from drivers.robot.gate import READBACK_GRACE, Emission
from drivers.robot.intake import Verdict
from drivers.robot.node import RobotNode
from drivers.robot.sim import SimRobot
from tests.drivers.robot.test_streaming_node import DT, HOME, JOINT_NAMES_UR, KEYS, LIMITS, Rig

GATE, AIM = 0, 1


class EmissionRig(Rig):
    """:class:`Rig` with the gate's emission rules (gate on output 0, aim on output 1)."""

    def __init__(self, **rules: Any) -> None:
        super().__init__(gate=False)
        self.sim = SimRobot(JOINT_NAMES_UR, HOME, LIMITS, realtime=False)
        emission = Emission(GATE, rules.pop("aim_output", AIM), **rules)
        self.node = RobotNode(self.bus, KEYS, "arm0", self.sim, LIMITS, clock=self.clock,
                              emission=emission).attach()  # fmt: skip
        self.bus.token(KEYS.alive("planner"))
        self.treat: list[bool] = []
        self.aim: list[bool] = []

    def period(self, n: int = 1) -> None:
        for _ in range(n):
            super().period()
            self.treat.append(self.sim.output(GATE))
            self.aim.append(self.sim.output(AIM))

    def hold(self, seconds: float, laser_on: list[list[float]] | None = None,
             aim_on: list[list[float]] | None = None, id: str = "T") -> None:  # fmt: skip
        """Accept a trajectory resting at HOME for ``seconds`` with the given intervals."""
        t = np.arange(0.0, seconds + DT / 2, DT)
        q = np.tile(HOME, (len(t), 1))
        z = np.zeros_like(q)
        spans = [None if v is None else np.asarray(v, dtype=float) for v in (laser_on, aim_on)]
        ref = Reference(t, q, z, z, *spans)
        self.node._decide(Verdict(self.clock.t, id, "S", ref, None))

    def lasers(self) -> list[dict[str, Any]]:
        return list(self.bus.published.get(KEYS.laser, []))

    def on_seconds(self) -> float:
        return DT * sum(self.treat)


def test_a_plain_interval_is_played_whole() -> None:
    rig = EmissionRig(power=0.05, max_on=2.0, max_spot_energy=0.5)
    rig.period(3)
    rig.hold(1.0, laser_on=[[0.2, 0.6]])
    rig.period(600)
    assert rig.node.ack is not None and rig.node.ack.accepted
    assert rig.on_seconds() == pytest.approx(0.4, abs=2 * DT)
    assert not rig.treat[-1] and rig.modes[-1] == "idle"
    assert rig.node.gate is not None and rig.node.gate.total_on == pytest.approx(0.4, abs=2 * DT)
    assert rig.node.gate.session_energy == pytest.approx(0.05 * 0.4, abs=0.05 * 2 * DT)


@pytest.mark.parametrize(
    "rules, limit_s, names",
    [({"power": 0.05, "max_spot_energy": 0.02}, 0.4, "max_spot_energy 0.02 J at 0.05 W"),
     ({"max_on": 0.25}, 0.25, "max_on 0.25 s")],
)  # fmt: skip
def test_a_dwell_over_a_limit_is_cut_at_the_limit_and_the_motion_aborted(
    rules: dict[str, Any], limit_s: float, names: str
) -> None:
    rig = EmissionRig(**rules)
    rig.period(3)
    rig.hold(2.0, laser_on=[[0.1, 1.9]])  # asks for 1.8 s of treatment
    rig.period(1200)
    # energy = power x on-time: the output was on for the limit, to one period
    assert rig.on_seconds() == pytest.approx(limit_s, abs=2 * DT)
    assert rig.modes[-1] in ("stopped", "braking") and rig.node.stopped_by is not None
    assert names in rig.node.stopped_by and "reached" in rig.node.stopped_by
    last = rig.lasers()[-1]
    assert last["on"] is False and names in last["reason"]


def test_the_session_energy_is_latched_until_the_driver_restarts() -> None:
    rig = EmissionRig(power=1.0, max_session_energy=0.5)
    rig.period(3)
    rig.hold(0.5, laser_on=[[0.1, 0.4]], id="a")  # 0.3 J
    rig.period(300)
    rig.hold(0.6, laser_on=[[0.1, 0.5]], id="b")  # 0.4 J asked: cut at 0.2 s (0.5 J)
    rig.period(400)
    assert rig.on_seconds() == pytest.approx(0.5, abs=2 * DT)
    assert rig.node.gate is not None and "max_session_energy 0.5 J" in (rig.node.gate.spent or "")
    rig.period(200)  # the arm rests after the abort
    rig.hold(0.5, laser_on=[[0.1, 0.4]], id="c")
    assert rig.node.ack is not None and not rig.node.ack.accepted
    assert "locked out: max_session_energy" in (rig.node.ack.reason or "")
    rig.hold(0.5, id="dark")  # a move without laser is still served
    assert rig.node.ack is not None and rig.node.ack.accepted


@pytest.mark.parametrize("speed", [0.1, 0.0])
def test_the_speed_slider_inside_an_interval_switches_treatment_off_and_aborts(
    speed: float,
) -> None:
    rig = EmissionRig()
    rig.period(3)
    rig.hold(1.0, laser_on=[[0.1, 0.3]])  # 0.2 s planned
    rig.period(100)  # 0.1 s into the interval... the gate opened at 0.1 s
    assert rig.treat[-1]
    rig.sim.speed = speed  # the operator drags the slider (0: pause)
    rig.period(2000)
    # today's gate stays on while the slowed clock plays the interval (2.0 s at 10 %,
    # for ever at 0 %): now it goes off in the period that sees the slider
    assert rig.on_seconds() <= 0.1 + 3 * DT
    assert not any(rig.treat[-1900:])
    assert rig.node.stopped_by is not None
    assert f"speed fraction {100 * speed:.0f} %" in rig.node.stopped_by
    assert rig.lasers()[-1]["on"] is False and "speed fraction" in rig.lasers()[-1]["reason"]


def test_a_slowed_arm_never_opens_the_gate() -> None:
    rig = EmissionRig()
    rig.sim.speed = 0.5
    rig.period(3)
    rig.hold(1.0, laser_on=[[0.1, 0.3]])
    rig.period(1500)
    assert not any(rig.treat) and "speed fraction 50 %" in (rig.node.stopped_by or "")


@pytest.mark.parametrize("stuck", ["high while off", "low while on"])
def test_a_read_back_mismatch_is_a_latched_fault(stuck: str) -> None:
    rig = EmissionRig()
    rig.period(3)
    rig.hold(1.0, laser_on=[[0.2, 0.8]])
    rig.period(50 if stuck == "high while off" else 200)  # before / inside the interval
    bit = 1 << GATE
    rig.sim.outputs = rig.sim.outputs | bit if stuck == "high while off" else rig.sim.outputs & ~bit
    rig.period(1)
    n = 1
    while rig.node.gate is not None and rig.node.gate.fault is None and n < 100:
        rig.period(1)
        n += 1
    # found in the period after the write's grace (at once when the write was long ago)
    assert n * DT <= READBACK_GRACE + 2 * DT
    fault = rig.node.gate.fault if rig.node.gate is not None else None
    assert fault is not None and f"laser output {GATE} reads" in fault
    assert rig.modes[-1] in ("braking", "stopped")
    rig.period(20)
    assert rig.status()["fault"] == fault
    assert rig.lasers()[-1]["on"] is False and "read-back" in rig.lasers()[-1]["reason"]
    rig.period(300)
    rig.hold(1.0, laser_on=[[0.2, 0.8]], id="again")
    assert rig.node.ack is not None and not rig.node.ack.accepted
    assert "locked out" in (rig.node.ack.reason or "")


def test_measurements_light_the_aim_output_only() -> None:
    rig = EmissionRig()
    rig.period(3)
    rig.hold(1.0, aim_on=[[0.2, 0.5]])
    rig.period(600)
    assert not any(rig.treat)
    assert DT * sum(rig.aim) == pytest.approx(0.3, abs=2 * DT)
    states = [m for m in rig.lasers() if m["aim"]]
    assert states and all(m["on"] is False for m in states)


def test_aim_gate_lights_the_gate_output_for_a_measurement() -> None:
    rig = EmissionRig(aim_output=GATE)  # aim: gate (a diagnostic diode is the only laser)
    rig.period(3)
    rig.hold(1.0, aim_on=[[0.2, 0.5]])
    rig.period(600)
    assert DT * sum(rig.treat) == pytest.approx(0.3, abs=2 * DT)  # the gate output is the diode
    assert any(m["aim"] and not m["on"] for m in rig.lasers())


def test_a_driver_without_an_aiming_beam_refuses_aim_on() -> None:
    rig = EmissionRig(aim_output=None)
    rig.period(3)
    rig.hold(1.0, aim_on=[[0.2, 0.5]])
    assert rig.node.ack is not None and not rig.node.ack.accepted
    assert "switches no aiming beam" in (rig.node.ack.reason or "")


class LaggingArm(SimRobot):
    """A simulated arm whose measured joints lag its command by ``offset`` (rad)."""

    offset = np.zeros(6)

    def measured(self) -> Any:
        m = super().measured()
        return m._replace(q=m.q + self.offset)


def test_the_spot_gain_bounds_the_spot_error_of_a_joint_error() -> None:
    from drivers.robot.following import REACH, spot_gain
    from planner.beam.trace import trace_beam
    from planner.io.scenario import load_scenario, system_from_scenario
    from tests.paths import REPO

    system = system_from_scenario(load_scenario(REPO / "scenarios" / "paper_n1.yaml"))
    gain = spot_gain(system, "arm0")
    q0 = system.home
    home = trace_beam(system, q0, np.zeros(3))
    target = home.hits[-1] + 0.6 * home.dirs[-1]  # a target 0.6 m down the beam (< REACH)
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = 1e-3
        moved = np.linalg.norm(trace_beam(system, q0 + dq, target).spot - target)
        assert moved <= gain[j] * 1e-3 * 1.01, j
    # the wrist joints tilt the mirror: 1 mrad turns the beam by 2 mrad, 1.2 mm at 0.6 m
    assert gain.max() > 2 * 0.6 and gain.max() < 2 * REACH * 1.5 + 1.5


@pytest.mark.parametrize("error_mm, trips", [(0.5, False), (2.0, True)])
def test_a_following_error_above_the_tolerance_switches_treatment_off(
    error_mm: float, trips: bool
) -> None:
    gain = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0)  # m/rad: only wrist_1 moves the spot, 1 mm / mrad
    rig = EmissionRig(following_gain=gain, following_tolerance=1e-3)
    rig.sim = LaggingArm(JOINT_NAMES_UR, HOME, LIMITS, realtime=False)
    rig.node = RobotNode(rig.bus, KEYS, "arm0", rig.sim, LIMITS, clock=rig.clock,
                         emission=rig.node.emission).attach()  # fmt: skip
    rig.bus.token(KEYS.alive("planner"))
    rig.period(3)
    rig.hold(1.0, laser_on=[[0.1, 0.6]])
    rig.period(200)  # inside the interval
    assert rig.treat[-1]
    LaggingArm.offset = np.array([0, 0, 0, error_mm * 1e-3, 0, 0])
    try:
        rig.period(400)
    finally:
        LaggingArm.offset = np.zeros(6)
    if trips:
        assert not any(rig.treat[-399:])
        assert "following error: the spot is off by up to 2.00 mm (> 1 mm" in (
            rig.node.stopped_by or ""
        )
    else:
        assert rig.on_seconds() == pytest.approx(0.5, abs=2 * DT) and rig.node.stopped_by is None


class StuckHigh(SimRobot):
    """A simulated arm whose gate output is welded high once it was switched on."""

    def set_output(self, output: int, on: bool) -> None:
        super().set_output(output, on or (output == GATE and self.output(GATE)))


def test_a_stuck_high_output_toggled_faster_than_the_grace_is_found() -> None:
    """20 ms on / 20 ms off intervals (shorter than the read-back grace) on a welded output:
    the gate may open again only once its last off is read back, so the weld is found
    within the grace of the first off."""
    rig = EmissionRig()
    rig.sim = StuckHigh(JOINT_NAMES_UR, HOME, LIMITS, realtime=False)
    rig.node = RobotNode(rig.bus, KEYS, "arm0", rig.sim, LIMITS, clock=rig.clock,
                         emission=rig.node.emission).attach()  # fmt: skip
    rig.bus.token(KEYS.alive("planner"))
    rig.period(3)
    spans = [[0.1 + 0.04 * k, 0.12 + 0.04 * k] for k in range(30)]
    rig.hold(1.5, laser_on=spans)
    rig.period(int(0.14 / DT))  # the first interval's off at 0.12 s, then 20 ms of grace
    n = 0
    while rig.node.gate is not None and rig.node.gate.fault is None and n < 200:
        rig.period(1)
        n += 1
    first_off = 0.12 + 3 * DT  # + the periods before the trajectory started
    found = 0.14 + 3 * DT + n * DT - first_off
    print(f"weld found {1e3 * found:.0f} ms after the first commanded off")
    assert rig.node.gate is not None and rig.node.gate.fault is not None
    assert "laser output 0 reads high, commanded low" in rig.node.gate.fault
    assert found <= READBACK_GRACE + 4 * DT  # the grace, plus the periods of the edge
    assert rig.modes[-1] in ("braking", "stopped")


def test_a_dwell_split_into_short_intervals_is_one_exposure() -> None:
    """20 intervals of 0.19 s with 4 ms gaps at one spot: max_on 0.25 s counts them as one."""
    rig = EmissionRig(max_on=0.25)
    rig.period(3)
    spans = [[0.1 + 0.194 * k, 0.29 + 0.194 * k] for k in range(20)]
    rig.hold(4.2, laser_on=spans)
    rig.period(2200)
    assert rig.on_seconds() == pytest.approx(0.25, abs=3 * DT)
    assert "max_on 0.25 s reached" in (rig.node.stopped_by or "")


def test_aim_gate_is_held_to_the_limits_too() -> None:
    """aim: gate: the diode lit for a measurement is the gate output; max_on cuts it, and the
    speed rule holds."""
    rig = EmissionRig(aim_output=GATE, max_on=0.25)
    rig.period(3)
    rig.hold(2.0, aim_on=[[0.1, 1.9]])
    rig.period(1200)
    assert rig.on_seconds() == pytest.approx(0.25, abs=3 * DT)
    assert "max_on 0.25 s reached" in (rig.node.stopped_by or "")


class DelayedArm(SimRobot):
    """A simulated arm that reaches its command ``delay`` periods late (a servoJ lookahead)."""

    delay = 25
    following_lag = 0.0

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self.history: list[np.ndarray] = []

    def measured(self) -> Any:
        m = super().measured()
        self.history.append(m.q.copy())
        return m._replace(q=self.history[max(len(self.history) - 1 - self.delay, 0)])


@pytest.mark.parametrize("lag, trips", [(0.0, True), (0.05, False)])
def test_the_following_check_allows_for_the_controllers_known_lag(lag: float, trips: bool) -> None:
    """A sweep at 0.2 rad/s on an arm 50 ms behind its command: 10 mrad of lag, 10 mm of
    spot at 1 mm/mrad. Compared with the command 50 ms earlier (the backend's known lag) it
    is on track; compared with the current command it is not."""
    rig = EmissionRig(following_gain=(0.0, 0.0, 0.0, 1.0, 0.0, 0.0), following_tolerance=1e-3)
    rig.sim = DelayedArm(JOINT_NAMES_UR, HOME, LIMITS, realtime=False)
    rig.sim.following_lag = lag
    rig.node = RobotNode(rig.bus, KEYS, "arm0", rig.sim, LIMITS, clock=rig.clock,
                         emission=rig.node.emission).attach()  # fmt: skip
    rig.bus.token(KEYS.alive("planner"))
    rig.period(30)
    t = np.arange(0.0, 1.0 + DT / 2, DT)
    s = np.clip((t - 0.1) / 0.8, 0, 1)  # a smooth ramp of wrist_1 by 0.1 rad
    smooth = s * s * (3 - 2 * s)
    q = np.tile(HOME, (len(t), 1))
    q[:, 3] += 0.1 * smooth
    qd = np.gradient(q, DT, axis=0)
    qdd = np.gradient(qd, DT, axis=0)
    rig.node._decide(
        Verdict(rig.clock.t, "sweep", "S", Reference(t, q, qd, qdd, np.array([[0.3, 0.7]])), None)
    )
    rig.period(700)
    if trips:
        assert rig.on_seconds() < 0.05 and "following error" in (rig.node.stopped_by or "")
    else:
        assert rig.on_seconds() == pytest.approx(0.4, abs=3 * DT) and rig.node.stopped_by is None
