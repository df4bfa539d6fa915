"""The simulated arm's servoJ lag against closed forms: a ramp trails by the lookahead time,
a step follows the second-order response the URScript semantics give."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.robot.follower import Reference
from drivers.robot.servo_lag import CYCLE, ServoLag, ServoSettings, follow
from drivers.robot.sim import SimRobot
from tests.drivers.robot.test_streaming_node import HOME, JOINT_NAMES_UR, LIMITS

SETTINGS = [ServoSettings(), ServoSettings(0.03, 2000.0), ServoSettings(0.2, 100.0)]


@pytest.mark.parametrize("s", SETTINGS)
def test_a_ramp_is_followed_one_lookahead_behind(s: ServoSettings) -> None:
    v = np.array([0.2, -0.1, 0.05])  # rad/s
    t = np.linspace(0.0, 4.0, 401)
    q_cmd = np.outer(t, v)
    arm = follow(t, q_cmd, s)
    late = t > 3.0  # the start transient (from rest) has died out
    np.testing.assert_allclose(q_cmd[late] - arm[late], np.tile(s.lookahead_time * v, (late.sum(), 1)),
                               rtol=1e-6)  # fmt: skip


@pytest.mark.parametrize("s", SETTINGS)
def test_a_step_follows_the_second_order_response(s: ServoSettings) -> None:
    # qdd = G (1 - q - L qd): natural frequency sqrt(G), damping L sqrt(G) / 2, from rest
    w, z = np.sqrt(s.gain), s.damping
    t = np.arange(0.0, 1.5, 1e-4)
    if np.isclose(z, 1.0):
        exact = 1 - (1 + w * t) * np.exp(-w * t)
    elif z < 1:
        wd = w * np.sqrt(1 - z * z)
        exact = 1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / np.sqrt(1 - z * z) * np.sin(wd * t))
    else:
        r1, r2 = -w * (z - np.sqrt(z * z - 1)), -w * (z + np.sqrt(z * z - 1))
        exact = 1 + (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r1 - r2)
    lag = ServoLag(np.zeros(1), s, dt=1e-4)
    sim = np.array([0.0, *(lag.step(np.ones(1))[0][0] for _ in t[1:])])
    np.testing.assert_allclose(sim, exact, atol=3e-3)


def test_at_the_controller_cycle_it_settles_on_a_held_target() -> None:
    lag = ServoLag(np.zeros(6))
    target = np.linspace(-0.3, 0.3, 6)
    for _ in range(int(3.0 / CYCLE)):
        q, qd = lag.step(target)
    np.testing.assert_allclose(q, target, atol=1e-9)
    np.testing.assert_allclose(qd, 0.0, atol=1e-8)


def _ramp(v: np.ndarray, duration: float) -> Reference:
    t = np.arange(0.0, duration + 1e-9, CYCLE)
    q = HOME + np.outer(t, v)
    return Reference(t, q, np.tile(v, (len(t), 1)), np.zeros_like(q))


def test_the_sim_arm_with_servo_trails_its_command_by_the_lookahead() -> None:
    s = ServoSettings()
    sim = SimRobot(JOINT_NAMES_UR, HOME, LIMITS, realtime=False, servo=s)
    assert sim.following_lag == s.lookahead_time
    v = np.array([0.1, -0.05, 0.05, 0.0, 0.1, -0.1])
    sim.command(_ramp(v, 3.0))
    for _ in range(int(2.5 / CYCLE)):
        m = sim.step()
    assert sim.follower.mode == "following"
    np.testing.assert_allclose(sim.follower.state.q - m.q, s.lookahead_time * v, atol=1e-9)
    np.testing.assert_allclose(m.qd, v, atol=1e-9)
    for _ in range(int(3.0 / CYCLE)):
        m = sim.step()
    np.testing.assert_allclose(m.q, HOME + 3.0 * v, atol=1e-9)


def test_the_sim_arm_without_servo_is_its_command() -> None:
    sim = SimRobot(JOINT_NAMES_UR, HOME, LIMITS, realtime=False)
    assert sim.following_lag == 0.0
    sim.command(_ramp(np.full(6, 0.1), 1.0))
    for _ in range(200):
        m = sim.step()
        np.testing.assert_array_equal(m.q, sim.follower.state.q)
