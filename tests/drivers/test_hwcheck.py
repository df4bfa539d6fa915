"""``beamrelay hw check`` on the simulated controller, and each check's failure path."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from types import SimpleNamespace
from typing import Any

import numpy as np

from drivers import hwcheck
from drivers.robot.ur import URRobot
from drivers.robot.ur_fake import FakeDashboard, FakeURController
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests.drivers.conftest import free_port

CLI = [sys.executable, "-m", "planner.cli", "hw", "check"]
ENV = dict(os.environ, PYTHONPATH=os.getcwd())


def test_simulated_system_passes_every_step() -> None:
    out = subprocess.run([*CLI, "--simulate", "--wiggle", "--gate-test", "--spot-test"],
                         capture_output=True, env=ENV, timeout=120)  # fmt: skip
    lines = out.stdout.decode().splitlines()
    assert out.returncode == 0, out.stdout + out.stderr
    marks = [ln.split("]")[0] + "]" for ln in lines[:-1]]
    assert marks == ["[PASS]"] * 4 + ["[SKIP]"] + ["[PASS]"] * 3
    assert [ln.split(":")[0].split("] ")[1] for ln in lines[:-1]] == [
        "network", "dashboard", "rtde", "registers", "camera", "wiggle", "gate", "spot"]  # fmt: skip
    assert lines[-1] == "8/8 ok"


def test_user_mistakes() -> None:
    for args in ([], ["--gate-output", "9", "--simulate"], ["--simulte"]):
        out = subprocess.run([*CLI, *args], capture_output=True, env=ENV, timeout=60)
        assert out.returncode == 2 and out.stderr.decode().count("\n") == 1, args


def test_unreachable_controller_fails_the_network_check() -> None:
    port = free_port()
    with socket.socket() as srv:  # one port open, one closed
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        c = hwcheck.check_ports("127.0.0.1", 1.0, (srv.getsockname()[1], port))
        assert c.status == "fail" and str(port) in c.detail and "29999" in c.todo
        ok = hwcheck.check_ports("127.0.0.1", 1.0, (srv.getsockname()[1],) * 2)
        assert ok.status == "pass"
    out = subprocess.run([*CLI, "--host", "127.0.0.1"], capture_output=True, env=ENV, timeout=60)
    assert out.returncode == 1 and out.stdout.decode().startswith("[FAIL] network")


def test_dashboard_and_rtde_failures_say_what_to_do() -> None:
    fake = FakeURController(DEFAULT_HOME)
    fake.remote_control = False
    fake.safety_mode = 3
    dash = FakeDashboard(fake)
    dash.version = "URSoftware 3.15.7"
    c = hwcheck.check_dashboard(dash)
    assert c.status == "fail"
    assert "Settings > System > Remote Control" in c.todo and "PolyScope 5" in c.todo
    assert "clear the safety stop" in c.todo
    fake.speed_scaling = 0.02
    r = hwcheck.check_rtde(fake, wait=0.01)  # nothing cycles: the timestamps stand still
    assert r.status == "fail" and "do not advance" in r.todo
    assert "protective stop" in r.todo and "raise the speed slider above 5 %" in r.todo


def test_register_conflict_names_the_fieldbus() -> None:
    def busy() -> Any:
        raise RuntimeError("One of the RTDE input registers are already in use! Currently you "
                           "must disable the EtherNet/IP adapter, PROFINET or any MODBUS unit")  # fmt: skip

    c, control = hwcheck.check_registers(busy)
    assert c.status == "fail" and control is None and "Installation > Fieldbus" in c.todo


def _device(usb: str, fw: str, modes: list[tuple[str, int, int, int]]) -> Any:
    info = {"name": "Intel RealSense D435", "serial_number": "123", "firmware_version": fw,
            "recommended_firmware_version": "5.16.0.1", "usb_type_descriptor": usb}  # fmt: skip
    profiles = [SimpleNamespace(is_video_stream_profile=lambda: True,
                                as_video_stream_profile=lambda m=m: SimpleNamespace(
                                    width=lambda: m[1], height=lambda: m[2]),
                                stream_type=lambda m=m: SimpleNamespace(name=m[0]),
                                fps=lambda m=m: m[3]) for m in modes]  # fmt: skip
    sensor = SimpleNamespace(get_stream_profiles=lambda: profiles)
    return SimpleNamespace(supports=lambda k: True, get_info=lambda k: info[k],
                           query_sensors=lambda: [sensor])  # fmt: skip


def test_camera_check() -> None:
    rs = SimpleNamespace(camera_info=SimpleNamespace(**{k: k for k in (
        "name", "serial_number", "firmware_version", "recommended_firmware_version",
        "usb_type_descriptor")}))  # fmt: skip
    good = [("depth", 848, 480, 30), ("color", 848, 480, 30)]
    assert hwcheck.check_camera([_device("3.2", "5.16.0.1", good)], rs).status == "pass"
    bad = hwcheck.check_camera([_device("2.1", "5.12.7.100", good[:1])], rs)
    assert bad.status == "fail"
    assert "USB 2.1" in bad.todo and "update it" in bad.todo and "modes not offered" in bad.todo
    none = hwcheck.check_camera([], rs)
    assert none.status == "fail" and "udev" in none.todo


def test_gate_that_does_not_read_back_fails() -> None:
    fake = FakeURController(DEFAULT_HOME)  # nothing cycles: outputs never update
    c = hwcheck.gate_test(fake, fake, 3, timeout=0.05)
    assert c.status == "fail" and "output 3 did not read back True" in c.detail


def test_spot_test_without_a_laser_fails() -> None:
    rng = np.random.default_rng(0)
    frame = lambda: rng.integers(90, 110, (60, 80, 3)).astype(np.uint8)  # noqa: E731
    c = hwcheck.spot_test(frame, lambda on: None)
    assert c.status == "fail" and "laser connected" in c.todo


def test_wiggle_fails_on_a_protective_stop() -> None:
    fake = FakeURController(DEFAULT_HOME)
    robot = URRobot("x", JOINT_NAMES_UR, Limits.ur_default(), control=fake, receive=fake)
    n = [0]

    def periods(k: int) -> None:
        for _ in range(k):
            n[0] += 1
            if n[0] == 300:
                fake.protective_stop()
            robot.begin_period()
            robot.step()
            robot.end_period()

    c = hwcheck.wiggle(robot, periods)
    assert c.status == "fail" and "protective stop" in c.detail
