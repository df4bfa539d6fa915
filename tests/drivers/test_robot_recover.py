"""``beamrelay robot recover`` against a UR driver on the simulated controller, and
``beamrelay up --backend ur``: one host per robot, no restart without the operator."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from drivers.robot.node import RobotNode
from planner.bus.session import Keys, open_session
from planner.errors import InputError
from planner.service.supervisor import Supervisor
from planner.service.up import child_commands, parse_hosts
from tests import cli_run
from tests.drivers.conftest import raw_session, wait_for
from tests.drivers.robot.test_robot_ur import LIMITS, make_robot
from tests.paths import REPO

CLI = [sys.executable, "-m", "planner.cli"]


def recover_cli(endpoint: str, prefix: str, *extra: str) -> subprocess.CompletedProcess[bytes]:
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    args = [*CLI, "robot", "recover", "--endpoint", endpoint, "--prefix", prefix, *extra]
    return subprocess.run(args, capture_output=True, env=env, timeout=90)


def test_recover_command_over_the_bus(hub: Any, endpoint: str, keys: Keys) -> None:
    robot, fake = make_robot()
    robot.robot = "arm0"
    fake.realtime = True
    session = open_session(listen=False, endpoint=endpoint)
    node = RobotNode(session, keys, "arm0", robot, LIMITS, require_planner=False).start()
    try:
        fake.protective_stop()
        wait_for(lambda: robot.measured().mode == "fault", what="fault")
        out = recover_cli(endpoint, keys.prefix, "--name", "arm0", "--timeout", "10")
        assert out.returncode == 1, out.stderr
        assert b"recover refused: protective stop" in out.stderr  # still stopped
        fake.release()
        wait_for(lambda: "cause cleared" in str(robot.measured().fault), what="cleared")
        out = recover_cli(endpoint, keys.prefix, "--name", "arm0", "--timeout", "10")
        assert out.returncode == 0, out.stderr
        assert out.stdout.decode().strip() == "arm0: idle (recovered by the operator)"
        assert fake.reuploads == 1 and fake.running
    finally:
        node.stop()
        session.close()


def test_recover_without_a_driver_and_user_mistakes(endpoint: str, hub: Any) -> None:
    out = recover_cli(endpoint, "brtest", "--name", "arm9", "--timeout", "1")
    assert out.returncode == 1
    assert out.stderr.decode().strip() == "arm9: no status from the driver within 1 s"
    for bad, needle in ((["--name", "arm/0"], "arm/0"), (["--name", "arm0", "--timeout", "-1"],
                        "--timeout"), (["--nmae", "arm0"], "--nmae")):  # fmt: skip
        bus = ["--endpoint", endpoint, "--prefix", "brtest"]
        cli_run.assert_usage_error(cli_run.beamrelay("robot", "recover", *bus, *bad), needle)


def test_parse_hosts() -> None:
    robots = ["arm0", "arm1"]
    assert parse_hosts(["arm0=10.0.0.1", "arm1=10.0.0.2"], robots, "ur") == {
        "arm0": "10.0.0.1", "arm1": "10.0.0.2"}  # fmt: skip
    bad = {
        ("arm0=10.0.0.1",): "add --host arm1=ADDRESS",
        ("arm0",): "expected NAME=ADDRESS",
        ("arm0=",): "expected NAME=ADDRESS",
        ("arm7=1.2.3.4", "arm0=1", "arm1=2"): "unknown robot 'arm7'",
        ("arm0=1", "arm0=2", "arm1=3"): "given twice",
    }
    for items, msg in bad.items():
        with pytest.raises(InputError, match=msg):
            parse_hosts(list(items), robots, "ur")
    with pytest.raises(InputError, match="only the ur backend"):
        parse_hosts(["arm0=1"], robots, "sim")
    argv = child_commands(Path("/s.yaml"), robots, backend="ur", endpoint="e",
                          hosts={"arm0": "10.0.0.1", "arm1": "10.0.0.2"})  # fmt: skip
    assert argv["arm1"][argv["arm1"].index("--host") + 1] == "10.0.0.2"


def test_manual_child_waits_for_the_operator(tmp_path: Path) -> None:
    crash = [sys.executable, "-c", "import sys; print('ran', flush=True); sys.exit(2)"]
    sup = Supervisor({"arm0": crash, "cam": crash}, tmp_path, manual=("arm0",))
    sup.start()
    t0 = time.monotonic()
    while time.monotonic() - t0 < 2.5:  # the automatic one restarts meanwhile
        sup.poll()
        time.sleep(0.02)
    arm = sup.children["arm0"]
    assert arm.restarts == 0 and arm.awaiting_operator and arm.last_exit == 2
    assert sup.children["cam"].restarts >= 1
    assert sup.restart("arm0") and not sup.restart("cam") and not sup.restart("nope")
    wait_for(lambda: not arm.running, what="second run")
    sup.stop()
    assert (tmp_path / "arm0.log").read_text().count("ran") == 2


def test_up_ur_does_not_restart_a_dead_driver_without_recover(tmp_path: Path) -> None:
    """No controller answers at the given host: the driver exits 2 and stays down; the
    operator's recover request restarts it once."""
    from tests.drivers.conftest import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    scenario = REPO / "scenarios" / "s_curve.yaml"  # the ur backend needs laser.gate
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    up = subprocess.Popen(
        [*CLI, "up", str(scenario), "--backend", "ur", "--host", "arm0=127.0.0.1",
         "--duration", "15", "--no-live", "--log-dir", str(tmp_path), "--endpoint", endpoint,
         "--prefix", "brup"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
    )  # fmt: skip
    log = tmp_path / "arm0.log"
    wait_for(lambda: log.exists() and "cannot connect" in log.read_text(), 30, "first run")
    time.sleep(2.0)  # well past the automatic restart delay
    assert log.read_text().count("cannot connect") == 1
    client = raw_session(endpoint)
    try:
        from drivers.robot.ur_link import recover_body

        wait_for(lambda: _put(client, "brup/arm0/recover", recover_body("arm0"), log), 15,
                 "restart on recover")  # fmt: skip
    finally:
        client.close()
    out, err = up.communicate(timeout=90)
    assert up.returncode == 0, err
    assert "arm0=2" in (out + err).decode()  # its exit code at the end: it was not restarted
    assert "restarted arm0 (operator recover)" in (out + err).decode()


def _put(client: Any, key: str, body: bytes, log: Path) -> bool:
    if log.read_text().count("cannot connect") >= 2:
        return True
    client.put(key, body)
    time.sleep(0.5)
    return log.read_text().count("cannot connect") >= 2
