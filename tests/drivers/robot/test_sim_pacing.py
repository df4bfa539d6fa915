"""The simulated arm's real-time pacing on an injected clock: simulated time keeps up with
wall time after a stall and never runs ahead of it (a sim that ran ahead moved the spot
faster than the plan: the spot-speed probe measured 20.9 mm/s for 20 mm/s)."""

from __future__ import annotations

import pytest

from drivers.robot.sim import MAX_CATCH_UP, SimRobot
from tests.drivers.robot.test_streaming_node import HOME, JOINT_NAMES_UR, LIMITS


class Wall:
    """A fake monotonic clock; sleeping advances it, each period costs ``work`` s."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        assert s >= 0
        self.t += s


@pytest.mark.parametrize("stall_periods", [0, 1, 3, MAX_CATCH_UP - 1, 3 * MAX_CATCH_UP])
def test_simulated_time_follows_wall_time_after_a_stall(stall_periods: int) -> None:
    wall = Wall()
    sim = SimRobot(JOINT_NAMES_UR, HOME, LIMITS, clock=wall, sleep=wall.sleep)
    steps = 0
    real_step = sim.follower.step

    def counted() -> None:
        nonlocal steps
        steps += 1
        real_step()

    sim.follower.step = counted  # type: ignore[method-assign]
    start = wall.t
    for k in range(400):
        sim.begin_period()
        if k == 100:
            wall.t += stall_periods * sim.dt  # the process was descheduled
        sim.step()
        wall.t += 0.3 * sim.dt  # the period's work
        sim.end_period()
    simulated, elapsed = steps * sim.dt, wall.t - start
    # behind by the backlog dropped when hopelessly late, never ahead (one period of slack)
    dropped = max(stall_periods + 1 - MAX_CATCH_UP, 0) * sim.dt
    assert simulated <= elapsed + sim.dt + 1e-9, (simulated, elapsed)
    assert simulated >= elapsed - dropped - sim.dt - 1e-9, (simulated, elapsed)
