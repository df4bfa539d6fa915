"""``beamrelay up``'s child command lines (the live behaviour is in tests/test_e2e.py)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

from planner.ros2 import messages as m
from planner.service.up import child_commands
from tests.paths import REPO


def test_child_commands_cover_every_node_with_the_bus_options() -> None:
    s = Path("/x/s.yaml")
    argv = child_commands(s, ["arm0", "arm1"], endpoint="tcp/127.0.0.1:9", prefix="p")
    assert list(argv) == ["planner", "camera", "arm0", "arm1"]
    bus = ["--endpoint", "tcp/127.0.0.1:9", "--prefix", "p"]
    cli = [sys.executable, "-m", "planner.cli"]
    assert argv["planner"] == [*cli, "serve", str(s), "--connect", *bus]
    assert argv["camera"] == [
        *cli,
        "driver",
        "camera",
        "--backend",
        "sim",
        "--scenario",
        str(s),
        *bus,
    ]
    assert argv["arm1"] == [
        *cli, "driver", "robot", "--name", "arm1", "--backend", "sim", "--scenario", str(s), *bus
    ]  # fmt: skip
    ur = child_commands(s, ["arm0"], backend="ur", endpoint="e", camera=False)
    assert list(ur) == ["planner", "arm0"] and "--prefix" not in ur["arm0"]
    assert ur["arm0"][ur["arm0"].index("--backend") + 1] == "ur"


def test_child_commands_pass_the_zenoh_configs_on() -> None:
    s, node, planner = Path("/x/s.yaml"), Path("/z/node.json5"), Path("/z/planner.json5")
    argv = child_commands(
        s, ["arm0"], endpoint="tcp/127.0.0.1:9", zenoh_config=node, planner_zenoh_config=planner
    )
    conf = {name: a[a.index("--zenoh-config") + 1] for name, a in argv.items()}
    assert conf == {"planner": str(planner), "camera": str(node), "arm0": str(node)}
    same = child_commands(s, ["arm0"], endpoint="e", zenoh_config=node)
    assert all(a[a.index("--zenoh-config") + 1] == str(node) for a in same.values())
    assert all(
        "--zenoh-config" not in a for a in child_commands(s, ["arm0"], endpoint="e").values()
    )


def test_child_commands_give_each_role_its_file() -> None:
    s = Path("/x/s.yaml")
    roles = {
        r: Path(f"/z/{r}.json5") for r in ("planner", "driver", "camera", "tracker", "console")
    }
    argv = child_commands(s, ["arm0", "arm1"], endpoint="e", tracker=True, console_port=8123,
                          role_configs=roles)  # fmt: skip
    conf = {name: a[a.index("--zenoh-config") + 1] for name, a in argv.items()}
    assert conf == {
        "planner": "/z/planner.json5", "camera": "/z/camera.json5", "tracker": "/z/tracker.json5",
        "arm0": "/z/driver.json5", "arm1": "/z/driver.json5", "console": "/z/console.json5",
    }  # fmt: skip
    assert all(a.count("--zenoh-config") == 1 for a in argv.values())
    roles["ros2"] = Path("/z/ros2.json5")
    argv = child_commands(s, ["arm0"], endpoint="e", role_configs=roles, ros_domain=0)
    bridge = argv["ros2"]
    assert bridge[bridge.index("--zenoh-config") + 1] == "/z/ros2.json5"  # its own identity


@pytest.mark.parametrize("files", ["node+planner", "roles"])
def test_up_on_a_locked_bus(tmp_path: Path, files: str) -> None:
    """``up`` with the shipped access-control examples: every child joins with its own
    identity (the planner's liveliness token is only accepted from the planner identity),
    and ``request --zenoh-config`` gets a plan; a client without credentials gets nothing.
    ``node+planner``: one identity for the planner, one for the rest; ``roles``: ``up
    --zenoh-roles``, one identity per role, the request with the console's."""
    import json
    import signal
    import socket
    import subprocess
    import time

    import zenoh

    root = REPO
    examples = root / "scenarios" / "zenoh"
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{sock.getsockname()[1]}"
    cli = [sys.executable, "-m", "planner.cli"]
    if files == "roles":  # with the ROS 2 bridge, as the ros2 identity
        up_files = ["--zenoh-roles", str(examples / "roles"), "--ros2"]
        client_file = examples / "roles" / "console.json5"
    else:
        up_files = ["--zenoh-config", str(examples / "acl-node.json5"),
                    "--planner-zenoh-config", str(examples / "acl-planner.json5")]  # fmt: skip
        client_file = examples / "acl-node.json5"
    up = subprocess.Popen(
        [*cli, "up", str(root / "scenarios" / "paper_n1.yaml"), "--endpoint", endpoint,
         "--no-live", "--duration", "120", "--log-dir", str(tmp_path),
         *up_files],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        conf = zenoh.Config.from_file(str(client_file))
        conf.insert_json5(
            "transport/auth/usrpwd/dictionary_file",
            json.dumps(str(client_file.parent / "credentials.txt")),
        )
        conf.insert_json5("access_control/enabled", "false")  # a client's own link: see bus.py
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("connect/timeout_ms", "30000")
        alive: set[str] = set()
        with zenoh.open(conf) as watcher:
            watcher.liveliness().declare_subscriber(
                "beamrelay/alive/**",
                lambda s: alive.add(str(s.key_expr).rsplit("/", 1)[-1]),
                history=True,
            )
            ros: list[Any] = []
            watcher.declare_subscriber("0/arm0/joint_states/**", ros.append)
            want = {"planner", "arm0"} | ({"ros2"} if files == "roles" else set())
            end = time.monotonic() + 90
            while not (want <= alive and (files != "roles" or ros)) and time.monotonic() < end:
                time.sleep(0.1)
            assert want <= alive, (alive, list(tmp_path.glob("*")))
            if files == "roles":  # the bridge's ROS 2 keys pass the access list
                assert ros, "no ROS 2 JointState from the bridge's ros2 identity"
                js = m.deserialize(ros[-1].payload.to_bytes(), m.JOINT_STATE)
                assert len(js.position) == 6
        req = subprocess.run(
            [*cli, "request", "--points", "-0.54,-0.57,-0.06", "--endpoint", endpoint,
             "--zenoh-config", str(client_file), "--timeout", "60"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert req.returncode in (0, 1), req.stderr
        assert "solved" in req.stdout
        outsider = subprocess.run(
            [*cli, "request", "--points", "-0.54,-0.57,-0.06", "--endpoint", endpoint,
             "--timeout", "3"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert outsider.returncode != 0 and "solved" not in outsider.stdout
        assert "Traceback" not in outsider.stderr
    finally:
        up.send_signal(signal.SIGTERM)
        out, _ = up.communicate(timeout=60)
    assert up.returncode == 0, out


def test_the_console_child_gets_its_port_and_the_bus() -> None:
    s = Path("/x/s.yaml")
    argv = child_commands(s, ["arm0"], endpoint="tcp/127.0.0.1:9", console_port=8123)
    assert list(argv) == ["planner", "camera", "arm0", "console"]
    assert argv["console"] == [sys.executable, "-m", "planner.cli", "console", str(s),
                               "--port", "8123", "--endpoint", "tcp/127.0.0.1:9"]  # fmt: skip
    assert "console" not in child_commands(s, ["arm0"], endpoint="e")


def test_child_commands_pass_the_online_calibration_file_to_the_planner_only() -> None:
    s, out = Path("/x/s.yaml"), Path("/x/online.yaml")
    argv = child_commands(s, ["arm0"], endpoint="e", online_calibration=out)
    assert argv["planner"][-2:] == ["--online-calibration", str(out)]
    assert "--online-calibration" not in argv["arm0"] + argv["camera"]
    assert "--online-calibration" not in child_commands(s, ["arm0"], endpoint="e")["planner"]


def test_the_ros2_bridge_child_gets_its_domain_and_the_bus() -> None:
    s = Path("/x/s.yaml")
    argv = child_commands(s, ["arm0"], endpoint="tcp/127.0.0.1:9", prefix="p", ros_domain=5)
    assert list(argv) == ["planner", "camera", "arm0", "ros2"]
    assert argv["ros2"] == [sys.executable, "-m", "planner.cli", "ros2", "bridge", str(s),
                            "--ros-domain", "5", "--endpoint", "tcp/127.0.0.1:9",
                            "--prefix", "p"]  # fmt: skip
    assert "ros2" not in child_commands(s, ["arm0"], endpoint="e")
