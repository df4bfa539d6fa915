"""Shared fixtures: small systems built in code (independent of the scenario loader)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.model.build import ur5e_robot
from planner.model.kinematics import RobotKinematics
from planner.model.system import DEFAULT_HOME, System
from planner.model.transforms import look_at, make_T, rpy_to_matrix


def make_system(n: int, seed: int = 0) -> System:
    """N UR5e robots on a circle, facing the centre, a laser aimed at robot 0's mirror."""
    rng = np.random.default_rng(seed)
    kin = RobotKinematics.ur5e()
    robots = []
    for i in range(n):
        ang = 2 * np.pi * i / max(n, 1)
        base = make_T(rpy_to_matrix([0, 0, ang + np.pi]), [1.2 * np.cos(ang), 1.2 * np.sin(ang), 0])
        mount = make_T(rpy_to_matrix(rng.uniform(-0.1, 0.1, 3)), rng.uniform(-0.01, 0.01, 3))
        mount[2, 3] += 0.03
        home = np.array(DEFAULT_HOME) + rng.uniform(-0.2, 0.2, 6)
        robots.append(ur5e_robot(f"arm{i}", base, flange_T_mirror=mount, home=home, kinematics=kin))
    first = robots[0]
    c = (first.world_T_base @ kin.fk(first.home) @ first.mirror.flange_T_mirror)[:3, 3]
    laser = look_at(c + np.array([0.3, 0.2, -0.4]), c)
    return System(laser, tuple(robots))


@pytest.fixture
def system1() -> System:
    return make_system(1)


def pytest_configure(config: pytest.Config) -> None:
    """Start Zenoh's runtime threads at the timing priority (when root): the tests are bus
    hubs routing heartbeats and watch 100 ms deadlines, like ``beamrelay up``'s hub. The
    runtime is process-wide and starts with the first session: open one, raised, first."""
    from planner.bus.priority import raised_priority
    from planner.bus.session import open_session
    from tests.drivers.conftest import free_port

    with raised_priority():
        open_session(listen=True, endpoint=f"tcp/127.0.0.1:{free_port()}").close()


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """With ``-m serial`` (``make test-system``), a test module whose text never says
    ``serial`` has no serial test: it is not imported (collecting all of them cost 14 s,
    the serial ones 7 s). The marker is only ever set in the module itself."""
    if config.option.markexpr != "serial" or collection_path.suffix != ".py":
        return None
    if not collection_path.name.startswith("test_"):
        return None
    return b"serial" not in collection_path.read_bytes() or None
