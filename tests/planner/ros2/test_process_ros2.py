"""``--ros2`` on ``serve`` and the drivers, without ``up`` and without the bridge process:
each process publishes its own topics as a ROS 2 node of its own (rmw_zenoh's liveliness
tokens), a raw Zenoh subscriber on rmw_zenoh's key pattern receives them, and rosbags'
deserializer decodes them: the robot driver's JointState and /tf, the camera's PointCloud2,
the planner's /tf_static. No process publishes another's topics; a bad domain exits 2."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from typing import Any

import numpy as np
import pytest

from planner.io.scenario import load_scenario, system_from_scenario
from planner.ros2 import messages as m
from tests.cli_run import assert_usage_error, beamrelay
from tests.drivers.conftest import free_port, raw_session, wait_for, wait_for_nodes
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "paper_n1.yaml"
CLI = [sys.executable, "-m", "planner.cli"]
ENV = dict(os.environ, PYTHONPATH=str(REPO))


def _node_tokens(client: Any, domain: int) -> dict[str, set[str]]:
    """Publisher topic names (unmangled) per ROS 2 node name, from the liveliness tokens."""
    replies = client.liveliness().get(f"@ros2_lv/{domain}/**", timeout=2.0)
    nodes: dict[str, set[str]] = {}
    for r in replies:
        if r.ok is None:
            continue
        parts = str(r.ok.key_expr).split("/")
        kind, node = parts[5], parts[8]
        nodes.setdefault(node, set())
        if kind == "MP":
            nodes[node].add(parts[9].replace("%", "/"))
    return nodes


@pytest.mark.serial  # three processes on a bus, a few seconds of traffic
def test_each_process_publishes_its_own_ros2_topics() -> None:
    prefix, ep, domain = "procros2", f"tcp/127.0.0.1:{free_port()}", 11
    bus = ["--endpoint", ep, "--prefix", prefix]
    ros = ["--ros2", "--ros-domain", str(domain)]
    procs = [
        subprocess.Popen([*CLI, "driver", "robot", "--name", "arm0", "--listen", "--scenario",
                          str(SCENARIO), *bus, *ros], stderr=subprocess.DEVNULL, env=ENV),
        subprocess.Popen([*CLI, "driver", "camera", "--scenario", str(SCENARIO), "--stride",
                          "16", *bus, *ros], stderr=subprocess.DEVNULL, env=ENV),
        subprocess.Popen([*CLI, "serve", str(SCENARIO), "--connect", *bus, *ros],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV),
    ]  # fmt: skip
    got: dict[str, list[Any]] = {"js": [], "tf": [], "cloud": [], "static": []}
    lock = threading.Lock()

    def on(name: str, ros_type: str) -> Any:
        def cb(s: Any) -> None:
            msg = m.deserialize(s.payload.to_bytes(), ros_type)
            with lock:
                got[name].append(msg)

        return cb

    try:
        wait_for_nodes(ep, prefix, ("arm0", "camera", "planner"))
        client = raw_session(ep)
        subs = [
            client.declare_subscriber(f"{domain}/arm0/joint_states/*/*", on("js", m.JOINT_STATE)),
            client.declare_subscriber(f"{domain}/tf/*/*", on("tf", m.TF_MESSAGE)),
            client.declare_subscriber(f"{domain}/camera/points/*/*", on("cloud", m.POINT_CLOUD2)),
            client.declare_subscriber(f"{domain}/tf_static/*/*", on("static", m.TF_MESSAGE)),
        ]
        wait_for(lambda: all(len(v) >= 2 for v in got.values()), 60.0, "every ROS 2 topic")
        nodes = _node_tokens(client, domain)
        for s in subs:
            s.undeclare()
        client.close()
    finally:
        for p in procs:
            p.terminate()
        codes = [p.wait(30) for p in procs]
    assert codes == [0, 0, 0], codes
    assert nodes["beamrelay_arm0"] == {"/arm0/joint_states", "/arm0/joint_trajectory", "/tf"}
    assert nodes["beamrelay_camera"] == {"/camera/points"}
    assert nodes["beamrelay_planner"] == {"/tf_static", "/beamrelay/markers",
                                          "/arm0/planned_trajectory"}  # fmt: skip
    system = system_from_scenario(load_scenario(SCENARIO))
    with lock:
        js, tf, cloud, static = (list(got[k]) for k in ("js", "tf", "cloud", "static"))
    assert js[-1].name == list(system.robots[0].joint_names)
    np.testing.assert_allclose(js[-1].position, system.robots[0].home, atol=1e-6)
    flange = tf[-1].transforms[0]
    assert (flange.header.frame_id, flange.child_frame_id) == ("arm0_base", "arm0_flange")
    expected = system.robots[0].kinematics.fk(np.asarray(js[-1].position))[:3, 3]
    t = flange.transform.translation
    np.testing.assert_allclose([t.x, t.y, t.z], expected, atol=1e-3)  # the arm is at rest
    c = cloud[-1]  # the board seen at stride 16: some tens of points
    assert c.header.frame_id == "camera" and c.width * c.height > 20
    assert len(c.data) == c.row_step * c.height == c.point_step * c.width * c.height
    assert "arm0_base" in {f.child_frame_id for f in static[-1].transforms}


@pytest.mark.parametrize(
    "argv",
    [
        ["serve", str(SCENARIO), "--ros2", "--ros-domain", "233"],
        ["driver", "robot", "--name", "arm0", "--scenario", str(SCENARIO), "--ros2",
         "--ros-domain", "-1"],
        ["driver", "camera", "--scenario", str(SCENARIO), "--ros2", "--ros-domain", "999"],
    ],
)  # fmt: skip
def test_a_domain_outside_ros_2s_range_is_refused_before_anything_starts(argv: list[str]) -> None:
    assert_usage_error(beamrelay(*argv), "--ros-domain")
