"""``beamrelay hw check``: bring-up checklist of a UR arm and a RealSense camera.

Read-only checks first; the steps that move the arm or switch outputs run only when asked
(``--wiggle``, ``--gate-test``, ``--spot-test``). ``--simulate`` runs everything against the
simulated controller (and rendered camera frames), as the tests do. Exit 0 when every
check passed, 1 when one failed. Steps and their fixes: :mod:`drivers.hwcheck`.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.cli.args import command_group
from planner.errors import InputError
from schemas import defaults

app = command_group(help="Hardware bring-up: checklist of the arm and the camera.")


# long: a typer command: 8 options (25 lines); the hardware check's steps follow in the order they run
@app.command("check")
def check(
    host: Annotated[
        str | None, typer.Option("--host", envvar="BEAMRELAY_UR_HOST", help="UR controller IP.")
    ] = None,
    camera: Annotated[bool, typer.Option(help="Check the RealSense camera.")] = True,
    wiggle: Annotated[
        bool, typer.Option("--wiggle", help="Opt-in: move wrist_3 +-0.05 rad at 0.1 rad/s.")
    ] = False,
    gate_test: Annotated[
        bool,
        typer.Option("--gate-test", help="Opt-in: toggle the gate output (laser disconnected!)."),
    ] = False,
    spot_test: Annotated[
        bool,
        typer.Option("--spot-test", help="Opt-in: aim beam on/off (laser.aim), find the spot."),
    ] = False,
    gate_output: Annotated[int, typer.Option(help="Standard digital output of the gate.")] = 0,
    scenario: Annotated[
        Path | None,
        typer.Option("--scenario", "-s", help="Scenario: the laser.gate and laser.aim outputs."),
    ] = None,
    simulate: Annotated[
        bool, typer.Option("--simulate", help="Run against the simulated controller.")
    ] = False,
) -> None:
    """Check the arm (network, dashboard, RTDE, registers) and the camera, then opt-in steps."""
    from drivers import hwcheck

    if host is None and not simulate:
        raise InputError("give the controller's address (or --simulate)", "--host")
    if not 0 <= gate_output <= 7:
        raise InputError(f"must be in [0, 7], got {gate_output}", "--gate-output")
    aim_output = None
    scn: Any = None
    if scenario is not None:
        from planner.io.scenario import load_scenario

        scn = load_scenario(scenario)
        laser = scn.model.system.laser
        if laser.gate is not None:
            gate_output = laser.gate.output
        if laser.aim is not None:
            aim_output = gate_output if laser.aim == "gate" else laser.aim.output
    if spot_test and aim_output is None:
        raise InputError("the spot test runs on the aiming beam only: the scenario (--scenario) "
                         "needs laser.aim", "laser.aim")  # fmt: skip
    outputs = sorted({gate_output} | ({aim_output} if aim_output is not None else set()))
    rig: Any = _SimRig() if simulate else _RealRig(str(host))
    results: list[hwcheck.Check] = []

    def report(c: hwcheck.Check) -> None:
        results.append(c)
        typer.echo(c.line())

    try:
        _read_only(rig, camera, report)
        if wiggle and all(c.status != "fail" for c in results):
            robot = rig.robot()
            report(hwcheck.wiggle(robot, lambda n: _periods(robot, n)))
        elif wiggle:
            report(_skipped("wiggle"))
        read_only_ok = all(c.status != "fail" for c in results)
        if gate_test and read_only_ok:
            report(hwcheck.gate_test(rig.io(), rig.receive, gate_output))
            report(hwcheck.runstate_test(rig.control, rig.receive, rig.io(), outputs))
        elif gate_test:
            report(_skipped("gate"))
        if spot_test and read_only_ok and aim_output is not None:
            aim = aim_output
            unsafe = hwcheck.aim_keep_out(scn, rig.receive.getActualQ())
            if unsafe is not None:
                report(unsafe)
            else:
                report(hwcheck.spot_test(rig.grab, lambda on: rig.set_gate(aim, on)))
        elif spot_test:
            report(_skipped("spot"))
    finally:
        _all_off(rig, outputs)
        rig.close()
    typer.echo("wiring RTDE cannot see (check each by hand before powering the laser):")
    for item in hwcheck.WIRING_CHECKLIST:
        typer.echo(f"  [ ] {item}")
    failed = [c.name for c in results if c.status == "fail"]
    typer.echo(f"{len(results) - len(failed)}/{len(results)} ok" +
               (f"; failed: {', '.join(failed)}" if failed else ""))  # fmt: skip
    if failed:
        raise typer.Exit(1)


def _all_off(rig: Any, outputs: list[int]) -> None:
    """Every laser output off (also after Ctrl-C or an error); a failure is printed."""
    for n in outputs:
        try:
            rig.io().setStandardDigitalOut(n, False)
        except Exception as exc:  # the link may be the reason we are here
            typer.echo(f"WARNING: could not switch output {n} off: {exc}", err=True)


def _skipped(name: str) -> Any:
    from drivers.hwcheck import Check

    return Check(name, "skip", "a read-only check failed: fix it first")


def _read_only(rig: Any, camera: bool, report: Any) -> None:
    from drivers import hwcheck

    net = rig.ports()
    report(net)
    if net.status != "pass":
        return
    report(hwcheck.check_dashboard(rig.dashboard()))
    report(hwcheck.check_rtde(rig.receive))
    regs, rig.control = hwcheck.check_registers(rig.open_control)
    report(regs)
    if camera:
        report(rig.camera_check())


class _RealRig:
    """The real interfaces (ur_rtde, pyrealsense2), opened lazily."""

    def __init__(self, host: str) -> None:
        self.host = host
        self.control: Any = None
        self._receive: Any = None
        self._io: Any = None
        self._cam: Any = None

    def ports(self) -> Any:
        from drivers.hwcheck import check_ports

        return check_ports(self.host)

    def dashboard(self) -> Any:
        from dashboard_client import DashboardClient

        d = DashboardClient(self.host)
        d.connect()
        return d

    @property
    def receive(self) -> Any:
        if self._receive is None:
            from rtde_receive import RTDEReceiveInterface

            self._receive = RTDEReceiveInterface(self.host, defaults.SERVO_RATE_HZ)
        return self._receive

    def open_control(self) -> Any:
        from rtde_control import RTDEControlInterface

        return RTDEControlInterface(self.host, defaults.SERVO_RATE_HZ)

    def camera_check(self) -> Any:
        import pyrealsense2 as rs

        from drivers.hwcheck import check_camera

        return check_camera(list(rs.context().query_devices()), rs)

    def robot(self) -> Any:
        from drivers.robot.ur import URRobot
        from planner.model.system import JOINT_NAMES_UR, Limits

        return URRobot(self.host, JOINT_NAMES_UR, Limits.ur_default(), control=self.control,
                       receive=self.receive)  # fmt: skip

    def io(self) -> Any:
        if self._io is None:
            from rtde_io import RTDEIOInterface

            self._io = RTDEIOInterface(self.host)
        return self._io

    def set_gate(self, output: int, on: bool) -> None:
        import time

        self.io().setStandardDigitalOut(output, on)
        time.sleep(0.1)  # let two frames pass with the new state

    def grab(self) -> Any:
        import numpy as np

        from drivers.camera.realsense import RealSenseCamera

        if self._cam is None:
            self._cam = RealSenseCamera()
        while not self._cam.grab():
            pass
        return np.asanyarray(self._cam._color.get_data()).copy()

    def close(self) -> None:
        for obj in (self._cam, self.control, self._receive, self._io):
            if obj is not None:
                with contextlib.suppress(RuntimeError):
                    obj.close() if hasattr(obj, "close") else obj.disconnect()


def _periods(robot: Any, n: int) -> None:
    for _ in range(n):
        robot.begin_period()
        robot.step()
        robot.end_period()


class _SimRig:
    """The simulated controller (:mod:`drivers.robot.ur_fake`, real-time paced) and a
    rendered camera whose laser is wired to the gate output."""

    def __init__(self) -> None:
        import numpy as np

        from drivers.robot.ur_fake import FakeURController
        from planner.model.system import DEFAULT_HOME

        self.fake = FakeURController(np.array(DEFAULT_HOME), realtime=True)
        self.receive = self.fake
        self.control: Any = None
        self._clock_on(True)  # the controller cycles by itself until a driver loop runs it
        self._rng = np.random.default_rng(0)
        self._gate_bit = 0

    def ports(self) -> Any:
        from drivers.hwcheck import Check

        return Check("network", "pass", "simulated controller (no network)")

    def dashboard(self) -> Any:
        from drivers.robot.ur_fake import FakeDashboard

        return FakeDashboard(self.fake)

    def open_control(self) -> Any:
        return self.fake

    def camera_check(self) -> Any:
        from drivers.hwcheck import Check

        return Check("camera", "skip", "simulated system: no camera device")

    def robot(self) -> Any:
        from drivers.robot.ur import URRobot
        from planner.model.system import JOINT_NAMES_UR, Limits

        self._clock_on(False)  # the driver's waitPeriod runs the cycles now
        return URRobot("sim", JOINT_NAMES_UR, Limits.ur_default(), control=self.fake,
                       receive=self.fake)  # fmt: skip

    def io(self) -> Any:
        self._clock_on(True)
        return self.fake

    def _clock_on(self, on: bool) -> None:
        import threading

        old = getattr(self, "_clock", None)
        if old is not None:
            old[0].set()
            old[1].join()
            self._clock = None
        if on:
            halt = threading.Event()
            thread = threading.Thread(target=self._cycles, args=(halt,), daemon=True)
            self._clock = (halt, thread)
            thread.start()

    def _cycles(self, halt: Any) -> None:
        while not halt.is_set():
            self.fake.waitPeriod()

    def set_gate(self, output: int, on: bool) -> None:
        import time

        self.fake.setStandardDigitalOut(output, on)
        self._gate_bit = output
        time.sleep(0.01)

    def grab(self) -> Any:
        import numpy as np

        vv, uu = np.mgrid[0:480, 0:848].astype(float)
        img = np.empty((480, 848, 3))
        img[:] = 100.0 + 50.0 * uu[..., None] / 848
        img[200:260, 40:100] = (230, 20, 20)  # a red object that is not the spot
        if self.fake.outputs >> self._gate_bit & 1:
            g = np.exp(-((uu - 500.3) ** 2 + (vv - 240.6) ** 2) / 8.0)
            img[..., 0] += 120 * g
        img += self._rng.normal(0, 2.0, img.shape)
        return np.clip(np.round(img), 0, 255).astype(np.uint8)

    def close(self) -> None:
        self._clock_on(False)
