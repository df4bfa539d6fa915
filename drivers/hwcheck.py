"""Bring-up checks of a UR arm and a RealSense camera (``beamrelay hw check``).

Read-only steps first, each a :class:`Check` (pass / fail / skip, the evidence, and what to
do when it fails):

1. ``network``: TCP connect to the controller's RTDE (30004) and dashboard (29999) ports;
2. ``dashboard``: PolyScope version (5.x for e-Series), robot mode (RUNNING), safety
   status (NORMAL), Remote Control (``isInRemoteControl``);
3. ``rtde``: the receive interface at 500 Hz: safety mode, speed slider (combined speed
   scaling; below the driver's floor it refuses trajectories), timestamps advancing;
4. ``registers``: the control interface (uploads ur_rtde's control script; no motion):
   fails when a fieldbus (EtherNet/IP, PROFINET, MODBUS) owns the RTDE input registers;
5. ``camera``: RealSense model, firmware (vs. the SDK's recommended), USB type (3.x), the
   848 x 480 @ 30 depth and colour modes.

Opt-in steps (they move the arm or switch outputs; the operator asks for each):

- ``wiggle``: wrist_3 +-0.05 rad and back at 0.1 rad/s peak through the real driver loop
  (:class:`drivers.robot.ur.URRobot`); passes when the arm tracks its command within
  :data:`WIGGLE_TRACKING` and comes to rest on the start;
- ``gate``: with the laser *disconnected*, the gate output is switched on and off through
  ``rtde_io``; the output bits read back over RTDE must follow, latency reported;
- ``runstate`` (with ``--gate-test``): every laser output set to go low at program stop,
  switched on, the control script stopped: the bit must read back low (the laser off when
  the driver dies);
- ``spot``: frames with the aim output off, then on (never the treatment gate; the scenario
  must have ``laser.aim``); the gated detector must find one spot.

Every laser output goes off at the end, also on Ctrl-C or an error; the gate and spot tests
are skipped after a failed read-only check. :data:`WIRING_CHECKLIST` is printed: the wiring
RTDE cannot see.

Every step takes the interfaces as arguments, so the tests run them on the simulated
controller (:mod:`drivers.robot.ur_fake`) and rendered frames.
"""

from __future__ import annotations

import re
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.camera.spot import detect_gated_spot
from drivers.robot.ur_link import MOTION_ALLOWED, safety_name
from planner.beam.trace import beam_vertices, trace_beam

RTDE_PORT, DASHBOARD_PORT = 30004, 29999
WIGGLE_AMPLITUDE = 0.05  # rad, wrist_3
WIGGLE_SPEED = 0.1  # rad/s peak
WIGGLE_TRACKING = 0.02  # rad: largest |measured - commanded| accepted while moving
GATE_LATENCY_MAX = 0.1  # s: the output must read back within this


@dataclass
class Check:
    """One checklist line."""

    name: str
    status: str  # "pass" | "fail" | "skip"
    detail: str
    todo: str = ""

    def line(self) -> str:
        mark = {"pass": "PASS", "fail": "FAIL", "skip": "SKIP"}[self.status]
        todo = f"\n         -> {self.todo}" if self.status == "fail" and self.todo else ""
        return f"[{mark}] {self.name}: {self.detail}{todo}"


def check_ports(
    host: str, timeout: float = 2.0, ports: tuple[int, int] = (RTDE_PORT, DASHBOARD_PORT)
) -> Check:
    closed = []
    for port in ports:
        try:
            with socket.create_connection((host, port), timeout=timeout):
                pass
        except OSError as exc:
            closed.append(f"{port} ({exc.strerror or exc})")
    if closed:
        return Check("network", "fail", f"{host}: cannot connect to {', '.join(closed)}",
                     "check the cable/IP (Settings > System > Network on the pendant) and "
                     "that no firewall blocks 30004 (RTDE) and 29999 (dashboard)")  # fmt: skip
    return Check("network", "pass", f"{host}: RTDE {ports[0]} and dashboard {ports[1]} open")


def check_dashboard(dash: Any) -> Check:
    version = str(dash.polyscopeVersion())
    mode, safety = str(dash.robotmode()), str(dash.safetystatus())
    remote = bool(dash.isInRemoteControl())
    detail = f"{version.strip()}; {mode.strip()}; {safety.strip()}; remote control {remote}"
    todo = []
    major = re.search(r"(\d+)\.\d+", version)
    if major is None or major.group(1) != "5":
        todo.append("this driver is tested with PolyScope 5 (e-Series)")
    if "RUNNING" not in mode.upper():
        todo.append("power on and release the brakes on the pendant")
    if "NORMAL" not in safety.upper() and "REDUCED" not in safety.upper():
        todo.append("clear the safety stop on the pendant")
    if not remote:
        todo.append("enable Settings > System > Remote Control, then switch the pendant to "
                    "Remote Control (top-right icon)")  # fmt: skip
    return Check("dashboard", "fail" if todo else "pass", detail, "; ".join(todo))


def check_rtde(receive: Any, floor: float = 0.05, wait: float = 0.1) -> Check:

    t0 = float(receive.getTimestamp())
    time.sleep(wait)
    t1 = float(receive.getTimestamp())
    mode = int(receive.getSafetyMode())
    speed = float(receive.getSpeedScalingCombined())
    detail = f"safety {safety_name(mode)}, speed slider {100 * speed:.0f} %, timestamps +{1e3 * (t1 - t0):.0f} ms"
    todo = []
    if t1 <= t0:
        todo.append("RTDE timestamps do not advance: another client or a dead link")
    if mode not in MOTION_ALLOWED:
        todo.append(f"clear the {safety_name(mode)} on the pendant")
    if speed < floor:
        todo.append(f"raise the speed slider above {100 * floor:.0f} %")
    return Check("rtde", "fail" if todo else "pass", detail, "; ".join(todo))


def check_registers(open_control: Callable[[], Any]) -> tuple[Check, Any]:
    try:
        control = open_control()
    except RuntimeError as exc:
        text = str(exc)
        todo = ("disable the EtherNet/IP adapter, PROFINET and MODBUS units that use the RTDE "
                "input registers (Installation > Fieldbus), or run ur_rtde with the upper "
                "register range" if "in use" in text.lower()
                else "check Remote Control and that no other program holds RTDE")  # fmt: skip
        return Check("registers", "fail", f"control interface: {text}", todo), None
    return Check("registers", "pass", "RTDE input registers free, control script running"), control


def check_camera(devices: list[Any], rs: Any) -> Check:
    if not devices:
        return Check("camera", "fail", "no RealSense device found",
                     "plug the D435 into a USB 3 port; install the udev rules "
                     "(99-realsense-libusb.rules)")  # fmt: skip
    dev = devices[0]
    info = {k: _info(dev, getattr(rs.camera_info, k)) for k in
            ("name", "serial_number", "firmware_version", "recommended_firmware_version",
             "usb_type_descriptor")}  # fmt: skip
    todo = []
    if not info["usb_type_descriptor"].startswith("3"):
        todo.append(f"USB {info['usb_type_descriptor'] or '?'}: use a USB 3 port and cable "
                    "(USB 2 has no 848 x 480 @ 30 depth + colour)")  # fmt: skip
    fw, rec = info["firmware_version"], info["recommended_firmware_version"]
    if fw and rec and _version(fw) < _version(rec):
        todo.append(f"firmware {fw} older than the recommended {rec}: update it")
    modes = _modes(dev, rs)
    if not {("depth", 848, 480, 30), ("color", 848, 480, 30)} <= modes:
        todo.append("848 x 480 @ 30 depth and colour modes not offered")
    detail = (
        f"{info['name']} #{info['serial_number']}, firmware {fw}, USB {info['usb_type_descriptor']}"
    )
    return Check("camera", "fail" if todo else "pass", detail, "; ".join(todo))


def _info(dev: Any, key: Any) -> str:
    return str(dev.get_info(key)) if dev.supports(key) else ""


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in text.split(".") if p.isdigit())


def _modes(dev: Any, rs: Any) -> set[tuple[str, int, int, int]]:
    out = set()
    for sensor in dev.query_sensors():
        for p in sensor.get_stream_profiles():
            if p.is_video_stream_profile():
                v = p.as_video_stream_profile()
                out.add((p.stream_type().name, v.width(), v.height(), p.fps()))
    return out


def wiggle(robot: Any, periods: Callable[[int], None]) -> Check:
    """Wrist_3 out and back at low speed through the driver (opt-in: the arm moves)."""
    from drivers.robot.follower import Reference

    q0 = np.asarray(robot.measured().q, dtype=float)
    duration = 2 * 1.875 * WIGGLE_AMPLITUDE / WIGGLE_SPEED  # min-jerk peak = 1.875 x mean
    t = np.arange(0.0, duration + 1e-9, robot.dt)
    x = np.clip(t / duration, 0, 1)
    s = np.sin(np.pi * (10 * x**3 - 15 * x**4 + 6 * x**5))  # 0 -> 1 -> 0
    q = np.tile(q0, (len(t), 1))
    q[:, -1] += WIGGLE_AMPLITUDE * s
    qd = np.gradient(q, t, axis=0)
    robot.command(Reference(t, q, qd, np.gradient(qd, t, axis=0)))
    worst, n = 0.0, 0
    while n < round(3 * duration / robot.dt):
        periods(1)
        n += 1
        m = robot.measured()
        if m.mode == "fault":
            return Check("wiggle", "fail", f"fault during the wiggle: {m.fault}", "see the fault")
        worst = max(worst, float(np.max(np.abs(m.q - robot.follower.q))))
        if m.mode == "idle" and not robot.servoing and n * robot.dt > duration:
            break
    end = float(np.max(np.abs(robot.measured().q - q0)))
    detail = f"tracking error max {1e3 * worst:.1f} mrad, back at start within {1e3 * end:.2f} mrad"
    ok = worst <= WIGGLE_TRACKING and end <= 1e-3
    return Check("wiggle", "pass" if ok else "fail", detail,
                 "check payload, servoJ gain/lookahead and the speed slider")  # fmt: skip


def gate_test(io: Any, receive: Any, output: int, timeout: float = 1.0) -> Check:
    """Switch the gate output on and off (laser disconnected!), read it back over RTDE."""
    lat = []
    for state in (True, False, True, False):
        t0 = time.monotonic()
        io.setStandardDigitalOut(output, state)
        while bool(int(receive.getActualDigitalOutputBits()) >> output & 1) != state:
            if time.monotonic() - t0 > timeout:
                return Check("gate", "fail", f"output {output} did not read back {state} within "
                             f"{timeout:g} s", "check the output number and the I/O setup")  # fmt: skip
            time.sleep(0.001)
        lat.append(time.monotonic() - t0)
    worst = max(lat)
    detail = f"output {output} switched 4 times, read back after {1e3 * min(lat):.0f}-{1e3 * worst:.0f} ms"
    ok = worst <= GATE_LATENCY_MAX
    return Check("gate", "pass" if ok else "fail", detail, "the RTDE link is slow or loaded")


#: m: how far along the aim beam the keep-out check of the spot test looks
SPOT_REACH = 2.0


def aim_keep_out(scn: Any, q: Any) -> Check | None:
    """The aim beam at the arm's measured joints ``q`` (rad) against the scenario's keep-out
    volumes (inflated by its margin), out to :data:`SPOT_REACH` m past the last mirror: a
    failed Check when it enters one (the spot test must not light it), else None."""

    from planner.io.scenario import system_from_scenario
    from planner.safety.model import Safety

    system = system_from_scenario(scn)
    if system.n_robots != 1:
        return Check("spot", "fail", f"the spot test reads one arm's joints; the scenario "
                     f"chains {system.n_robots}", "run it on a one-arm scenario of this cell")  # fmt: skip
    q = np.asarray(q, dtype=float)
    tr = trace_beam(system, q, np.zeros(3))
    end = tr.hits[-1] + SPOT_REACH * tr.dirs[-1]
    tr = trace_beam(system, q, end)
    bad = Safety.from_scenario(scn, system).geometry(beam_vertices(system, tr.hits, tr.spot))
    if bad is None:
        return None
    return Check("spot", "fail", f"not lit: the aim beam at the arm's joints would enter a "
                 f"keep-out volume ({bad.text})", "move the arm so the beam points away from "
                 "every keep-out volume")  # fmt: skip


def spot_test(grab: Callable[[], Any], set_gate: Callable[[bool], None], frames: int = 3) -> Check:
    """Frames with the gate off, then on: the gated detector must find the spot."""

    set_gate(False)
    off = [grab() for _ in range(frames)]
    set_gate(True)
    on = [grab() for _ in range(frames)]
    set_gate(False)
    found = detect_gated_spot(on, off)
    if found is None:
        return Check("spot", "fail", "no spot in the on/off difference",
                     "laser connected and aimed into the view? exposure too high (saturation)?")  # fmt: skip
    return Check("spot", "pass", f"spot at ({found.u:.1f}, {found.v:.1f}) px, confidence "
                 f"{found.confidence:.2f}, {found.pixels} px")  # fmt: skip


def runstate_test(control: Any, receive: Any, io: Any, outputs: list[int],
                  timeout: float = 1.0) -> Check:  # fmt: skip
    """Off at program stop, on the controller (laser *unpowered*!): configure each laser
    output to go low when the program stops (``set_runstate_standard_digital_output_to_value
    (n, 1)``, as the driver does), switch it on, stop the control script and read the bit
    back: it must be low without any write; the script is re-uploaded after."""
    script = "".join(f"  set_runstate_standard_digital_output_to_value({n}, 1)\n" for n in outputs)
    if control.sendCustomScriptFunction("beamrelay_laser_runstate", script) is False:
        return Check("runstate", "fail", "the controller refused the runstate script",
                     "PolyScope 5.x in Remote Control? the outputs free (no installation I/O action)?")  # fmt: skip
    mask = sum(1 << n for n in outputs)
    for n in outputs:
        io.setStandardDigitalOut(n, True)
    t0 = time.monotonic()
    while int(receive.getActualDigitalOutputBits()) & mask != mask:
        if time.monotonic() - t0 > timeout:
            return Check("runstate", "fail", f"outputs {outputs} did not read back on",
                         "check the output numbers")  # fmt: skip
        time.sleep(0.001)
    control.stopScript()
    t0 = time.monotonic()
    while int(receive.getActualDigitalOutputBits()) & mask:
        if time.monotonic() - t0 > timeout:
            for n in outputs:
                io.setStandardDigitalOut(n, False)
            control.reuploadScript()
            return Check("runstate", "fail", f"outputs {outputs} stayed on {timeout:g} s after "
                         "the program stopped", "the laser would stay on when the driver dies: "
                         "check the I/O setup of the installation")  # fmt: skip
        time.sleep(0.001)
    lat = time.monotonic() - t0
    control.reuploadScript()
    return Check("runstate", "pass", f"outputs {outputs} dropped {1e3 * lat:.0f} ms after the "
                 "control script stopped (low when not running)")  # fmt: skip


#: the wiring RTDE cannot see: the operator confirms each before the laser is powered
WIRING_CHECKLIST = (
    "laser remote interlock wired through a UR *safety* output (not a standard one): "
    "opens on e-stop and protective stop",
    "e-stop buttons cut the laser's interlock, tested with the laser unpowered",
    "treatment footswitch (dead-man) in series with the gate output, tested",
    "gate and aim outputs wired to the laser's TTL gate / pilot inputs, nothing else on them",
    "beam dump / shutter closed by default, eye protection for the wavelength in the room",
)
