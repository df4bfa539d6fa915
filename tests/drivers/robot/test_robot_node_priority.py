"""A driver's control loop thread runs under SCHED_FIFO where permitted (the other threads
of the process stay normal) and never holds a core through a period."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from drivers.robot.node import RobotNode
from drivers.robot.sim import SimRobot
from planner.bus.priority import RT_PRIORITY, Policy
from planner.bus.session import Keys
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests.drivers.robot.fake_bus import FakeBus


def run_node(realtime: bool) -> tuple[RobotNode, tuple[int, int]]:
    """Start a sim node for 0.3 s; the node and its loop thread's (policy, priority)."""
    limits = Limits.ur_default()
    backend = SimRobot(JOINT_NAMES_UR, np.array(DEFAULT_HOME), limits, rate=500.0)
    node = RobotNode(FakeBus(), Keys("prio"), "arm0", backend, limits, realtime=realtime)
    node.start()
    try:
        time.sleep(0.3)
        assert node._thread is not None and node._thread.native_id is not None
        tid = node._thread.native_id
        sched = os.sched_getscheduler(tid) & ~os.SCHED_RESET_ON_FORK
        return node, (sched, os.sched_getparam(tid).sched_priority)
    finally:
        node.stop()


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root")
def test_as_root_the_control_loop_thread_runs_under_sched_fifo_and_the_rest_normal() -> None:
    node, loop = run_node(realtime=True)
    assert loop == (os.SCHED_FIFO, RT_PRIORITY)
    assert node.loop_priority is not None and node.loop_priority.policy is Policy.FIFO
    assert os.sched_getscheduler(threading.get_native_id()) == os.SCHED_OTHER
    assert node.n_periods > 100  # it ran at 500 Hz, sleeping every period


def test_without_realtime_the_loop_is_left_as_it_was() -> None:
    node, loop = run_node(realtime=False)
    assert loop == (os.SCHED_OTHER, 0) and node.loop_priority is None
