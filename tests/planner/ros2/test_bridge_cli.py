"""``beamrelay ros2 bridge`` on a running simulated robot driver: a raw Zenoh subscriber on
rmw_zenoh's key pattern (type hash as a wildcard chunk) gets JointStates whose stamps and
positions are the driver's own bus samples, decoded with rosbags' deserializer."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np
import pytest

from planner.ros2 import messages as m
from tests.drivers.conftest import free_port, raw_session, wait_for, wait_for_nodes
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "paper_n1.yaml"
CLI = [sys.executable, "-m", "planner.cli"]
ENV = dict(os.environ, PYTHONPATH=os.getcwd())


@pytest.mark.serial  # two processes on the bus, a few seconds of traffic
def test_bridge_process_republishes_the_drivers_joint_states() -> None:
    prefix, ep, domain = "brros2", f"tcp/127.0.0.1:{free_port()}", 9
    bus = ["--endpoint", ep, "--prefix", prefix]
    robot = subprocess.Popen([*CLI, "driver", "robot", "--name", "arm0", "--listen",
                              "--scenario", str(SCENARIO), *bus],
                             stderr=subprocess.DEVNULL, env=ENV)  # fmt: skip
    bridge = subprocess.Popen([*CLI, "ros2", "bridge", str(SCENARIO), "--ros-domain",
                               str(domain), *bus], stderr=subprocess.PIPE, env=ENV)  # fmt: skip
    got: dict[str, list[Any]] = {"ros": [], "bus": []}
    lock = threading.Lock()

    def on_ros(s: Any) -> None:
        with lock:
            got["ros"].append(m.deserialize(s.payload.to_bytes(), m.JOINT_STATE))

    def on_bus(s: Any) -> None:
        with lock:
            got["bus"].append(json.loads(s.payload.to_bytes()))

    try:
        wait_for_nodes(ep, prefix, ("arm0", "ros2"))
        client = raw_session(ep)
        subs = [
            client.declare_subscriber(
                f"{domain}/arm0/joint_states/sensor_msgs::msg::dds_::JointState_/*", on_ros
            ),
            client.declare_subscriber(f"{prefix}/arm0/joint_states", on_bus),
        ]
        # the client links to the bridge by gossip, the bridge warms up: count once it flows
        wait_for(lambda: len(got["ros"]) > 20, 60.0, "ROS 2 joint states flowing")
        with lock:
            got["ros"].clear()
        time.sleep(2.0)
        for s in subs:
            s.undeclare()
        client.close()
    finally:
        for p in (bridge, robot):
            p.terminate()
            p.wait(30)
    assert bridge.returncode == 0, bridge.stderr.read() if bridge.stderr else ""
    with lock:
        ros, bus_msgs = list(got["ros"]), list(got["bus"])
    assert len(ros) > 50, f"{len(ros)} ROS 2 joint states in 2 s"
    by_stamp = {round(b["t"] * 1e6): b for b in bus_msgs}
    matched = 0
    for js in ros:
        t = js.header.stamp.sec + js.header.stamp.nanosec * 1e-9
        b = by_stamp.get(round(t * 1e6))
        if b is None:
            continue  # published just before the bus subscription began
        matched += 1
        assert js.name == b["names"]
        np.testing.assert_array_equal(js.position, b["q"])
        np.testing.assert_array_equal(js.velocity, b["qd"])
    assert matched > 0.9 * len(ros)
