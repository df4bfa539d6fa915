"""``beamrelay hw check`` on the simulated controller, and each check's failure path."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from drivers import hwcheck
from drivers.robot.ur import URRobot
from drivers.robot.ur_fake import FakeDashboard, FakeURController
from planner.cli.hw import _SimRig
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests import cli_run
from tests.drivers.conftest import free_port
from tests.paths import REPO

SimRig = _SimRig  # bound before any monkeypatch of the module

CLI = [sys.executable, "-m", "planner.cli", "hw", "check"]
ENV = dict(os.environ, PYTHONPATH=os.getcwd())


def aimed_scenario(tmp_path: Path, aim: str = "{robot: arm0, output: 4}") -> Path:
    """s_curve (laser.gate: arm0 output 0) with an aiming beam on output 4."""
    text = (REPO / "scenarios" / "s_curve.yaml").read_text()
    gate = "    gate: {robot: arm0, output: 0}\n"
    assert gate in text
    out = tmp_path / "aimed.yaml"
    out.write_text(text.replace(gate, gate + f"    aim: {aim}\n"))
    return out


def test_simulated_system_passes_every_step(tmp_path: Path) -> None:
    out = subprocess.run([*CLI, "--simulate", "--wiggle", "--gate-test", "--spot-test",
                          "--scenario", str(aimed_scenario(tmp_path))],
                         capture_output=True, env=ENV, timeout=120)  # fmt: skip
    lines = out.stdout.decode().splitlines()
    assert out.returncode == 0, out.stdout + out.stderr
    checks = [ln for ln in lines if ln.startswith("[")]
    marks = [ln.split("]")[0] + "]" for ln in checks]
    assert marks == ["[PASS]"] * 4 + ["[SKIP]"] + ["[PASS]"] * 4
    assert [ln.split(":")[0].split("] ")[1] for ln in checks] == [
        "network", "dashboard", "rtde", "registers", "camera", "wiggle", "gate", "runstate",
        "spot"]  # fmt: skip
    assert "outputs [0, 4] dropped" in checks[7]
    wiring = lines.index("wiring RTDE cannot see (check each by hand before powering the laser):")
    assert lines[wiring + 1 : -1] == [f"  [ ] {w}" for w in hwcheck.WIRING_CHECKLIST]
    assert any("safety* output" in w for w in hwcheck.WIRING_CHECKLIST)
    assert lines[-1] == "9/9 ok"


def test_spot_test_refuses_without_an_aiming_beam(tmp_path: Path) -> None:
    for extra in ([], ["--scenario", str(REPO / "scenarios" / "s_curve.yaml")]):
        out = cli_run.beamrelay("hw", "check", "--simulate", "--spot-test", *extra)
        cli_run.assert_usage_error(out, "laser.aim")


def make_rig(read_only_fail: bool = False, grab_raises: BaseException | None = None) -> Any:
    """The simulated rig of ``hw check --simulate`` whose network check fails or whose
    grab() raises once an output is on; it records every output switch."""

    class Rig(SimRig):
        def __init__(self) -> None:
            super().__init__()
            self.gate_calls: list[tuple[int, bool]] = []

        def ports(self) -> Any:
            return hwcheck.Check("network", "fail" if read_only_fail else "pass", "test rig")

        def set_gate(self, output: int, on: bool) -> None:
            self.gate_calls.append((output, on))
            super().set_gate(output, on)

        def grab(self) -> Any:
            if grab_raises is not None and any(on for _, on in self.gate_calls):
                raise grab_raises
            return super().grab()

    return Rig()


def run_check(monkeypatch: Any, rig: Any, tmp_path: Path, *args: str) -> Any:
    from typer.testing import CliRunner

    from planner.cli import hw

    monkeypatch.setattr(hw, "_SimRig", lambda: rig)
    return CliRunner().invoke(hw.app, ["--simulate", "--no-camera", "--scenario",
                                       str(aimed_scenario(tmp_path)), *args])  # fmt: skip


def test_every_laser_output_off_when_grab_raises_or_on_ctrl_c(
    monkeypatch: Any, tmp_path: Path
) -> None:
    for exc in (RuntimeError("frame timeout"), KeyboardInterrupt()):
        rig = make_rig(grab_raises=exc)
        fake = rig.fake
        run_check(monkeypatch, rig, tmp_path, "--spot-test")
        assert (4, True) in rig.gate_calls  # the aim output was on when grab() raised
        assert all(n == 4 for n, _ in rig.gate_calls)  # never the treatment gate (0)
        fake.cycle()
        assert fake.outputs == 0, exc


def test_gate_and_spot_tests_skipped_after_a_failed_read_only_check(
    monkeypatch: Any, tmp_path: Path
) -> None:
    rig = make_rig(read_only_fail=True)
    fake = rig.fake
    out = run_check(monkeypatch, rig, tmp_path, "--gate-test", "--spot-test")
    assert out.exit_code == 1
    assert "[SKIP] gate: a read-only check failed" in out.stdout
    assert "[SKIP] spot: a read-only check failed" in out.stdout
    assert rig.gate_calls == [] and "setStandardDigitalOut" not in fake.calls


def test_runstate_check_fails_when_the_output_stays_on_at_program_stop() -> None:
    fake = FakeURController(np.array(DEFAULT_HOME))
    fake.sendCustomScriptFunction = lambda name, script: True  # type: ignore[method-assign]
    import threading

    halt = threading.Event()
    clock = threading.Thread(target=lambda: [fake.cycle() or halt.wait(0.002)
                                             for _ in iter(halt.is_set, True)])  # fmt: skip
    clock.start()
    try:
        c = hwcheck.runstate_test(fake, fake, fake, [0], timeout=0.05)
    finally:
        halt.set()
        clock.join()
    assert c.status == "fail" and "stayed on" in c.detail
    fake.cycle()
    assert fake.outputs == 0 and fake.running  # switched off, script re-uploaded


def test_user_mistakes() -> None:
    for args in ([], ["--gate-output", "9", "--simulate"], ["--simulte"]):
        cli_run.assert_usage_error(cli_run.beamrelay("hw", "check", *args))


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


def test_the_spot_test_does_not_light_an_aim_beam_that_would_enter_a_keep_out(
    monkeypatch: Any, tmp_path: Path
) -> None:
    """A keep-out sphere on the aim beam at the arm's joints: the spot test fails without
    switching the aim output on."""
    import numpy as np

    from planner.beam.trace import trace_beam
    from planner.io.scenario import load_scenario, system_from_scenario
    from planner.model.system import DEFAULT_HOME

    path = aimed_scenario(tmp_path)
    system = system_from_scenario(load_scenario(path))
    tr = trace_beam(system, np.array(DEFAULT_HOME), np.zeros(3))
    eye = tr.hits[-1] + 0.3 * tr.dirs[-1]  # 0.3 m down the beam from the mirror
    text = path.read_text()
    extra = f"\nkeep_out:\n  - {{name: eye, sphere: 0.01, world_T_object: {{xyz: {eye.round(4).tolist()}}}}}\n"
    path.write_text(text + extra if "keep_out:" not in text else text)
    assert "keep_out:" in path.read_text()
    rig = make_rig()
    from typer.testing import CliRunner

    from planner.cli import hw

    monkeypatch.setattr(hw, "_SimRig", lambda: rig)
    out = CliRunner().invoke(hw.app, ["--simulate", "--no-camera", "--scenario", str(path),
                                      "--spot-test"])  # fmt: skip
    assert out.exit_code == 1, out.output
    assert (
        "[FAIL] spot: not lit: the aim beam at the arm's joints would enter a keep-out"
        in out.output
    )
    assert "keep_out/eye" in out.output
    assert (4, True) not in rig.gate_calls  # the aim output never went on
