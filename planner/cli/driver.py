"""``beamrelay driver robot|camera``: run one driver process on the Zenoh bus.

Light imports only at module level (``beamrelay --help`` stays instant). Both commands run
until Ctrl-C or SIGTERM, then stop the hardware (``servoStop`` / pipeline stop), withdraw
their liveliness token and close the session.
"""

from __future__ import annotations

import signal
from enum import StrEnum
from pathlib import Path
from typing import Any

import typer

from planner.cli.args import command_group
from schemas import defaults

app = command_group(help="Robot and camera drivers (simulated or real) for the running system.")

SCENARIO = typer.Option(
    ..., "--scenario", "-s", help="Scenario YAML (robots, limits, camera, scene)."
)
ENDPOINT = typer.Option(
    None,
    "--endpoint",
    help="Bus endpoint (default $BEAMRELAY_ZENOH_ENDPOINT or tcp/127.0.0.1:7447).",
)
ZCONFIG = typer.Option(
    None, "--zenoh-config", help="Zenoh config file (routers, TLS, access control)."
)
PREFIX = typer.Option("beamrelay", "--prefix", help="Key namespace prefix.")
LISTEN = typer.Option(
    False, "--listen", help="Listen on the endpoint (when no planner node hosts the bus)."
)


class RobotBackendName(StrEnum):
    sim = "sim"
    ur = "ur"


class CameraBackendName(StrEnum):
    sim = "sim"
    realsense = "realsense"


ROBOT_BACKEND = typer.Option(RobotBackendName.sim, "--backend", help="sim or ur.")
CAMERA_BACKEND = typer.Option(CameraBackendName.sim, "--backend", help="sim or realsense.")
DB3_RECORD = typer.Option(
    None, "--record", help="realsense device: also record the raw streams to this .db3."
)
ROS2 = typer.Option(
    False,
    "--ros2",
    help="Also publish this driver's ROS 2 topics (rmw_zenoh key expressions),"
    " from a thread and Zenoh session of their own.",
)
ROS_DOMAIN = typer.Option(0, "--ros-domain", help="ROS_DOMAIN_ID of the ROS 2 topics (0-232).")
RECORDING = typer.Option(
    None, "--file", help="realsense: play a .db3 recording (librealsense 2.59) instead of a device."
)


# long: a typer command: 19 options declared in its signature (43 lines); one backend is built from them and run
@app.command("robot")
def robot(
    name: str = typer.Option(..., "--name", help="Robot name in the scenario (e.g. arm0)."),
    backend: RobotBackendName = ROBOT_BACKEND,
    scenario: Path = SCENARIO,
    host: str | None = typer.Option(
        None, "--host", envvar="BEAMRELAY_UR_HOST", help="UR controller IP (backend ur)."
    ),
    endpoint: str | None = ENDPOINT,
    zenoh_config: Path | None = ZCONFIG,
    prefix: str = PREFIX,
    listen: bool = LISTEN,
    rate: float = typer.Option(defaults.SERVO_RATE_HZ, "--rate", help="Control rate, Hz."),
    state_rate: float = typer.Option(250.0, "--state-rate", help="joint_states rate, Hz (>= 100)."),
    lookahead: float = typer.Option(
        defaults.SERVOJ_LOOKAHEAD_S, "--lookahead", help="servoJ lookahead time, s [0.03, 0.2]."
    ),
    gain: float = typer.Option(defaults.SERVOJ_GAIN, "--gain", help="servoJ gain [100, 2000]."),
    servo_lag: bool = typer.Option(
        False,
        "--servo-lag/--no-servo-lag",
        help="sim: the arm follows its command as a UR follows servoJ (--lookahead, --gain).",
    ),
    watchdog_hz: float = typer.Option(
        25.0,
        "--rtde-watchdog",
        help="RTDE watchdog minimum rate, Hz (25: a dead driver's laser is off in < 100 ms).",
    ),
    start_tolerance: float = typer.Option(
        0.01, "--start-tolerance", help="Largest start offset accepted, rad."
    ),
    require_planner: bool = typer.Option(
        True,
        "--require-planner/--no-require-planner",
        help="Refuse to move without a live planner and its heartbeat (off: bench work only).",
    ),
    realtime: bool = typer.Option(
        False,
        "--realtime",
        help="ur: SCHED_FIFO for the control loop and ur_rtde's threads (when permitted).",
    ),
    ros2: bool = ROS2,
    ros_domain: int = ROS_DOMAIN,
) -> None:
    """Run a robot driver: joint_states, status, trajectories, planner heartbeat watchdog.
    With --ros2 its joint states, /tf (base -> flange), the trajectories it is sent and, on
    the gate's driver, the laser state are on ROS 2 too (node beamrelay_NAME)."""
    from planner.cli.ros2 import check_domain

    if ros2:
        check_domain(ros_domain)
    from drivers.robot.following import spot_gain
    from drivers.robot.gate import Emission
    from drivers.robot.node import RobotNode
    from planner.bus import events
    from planner.bus.priority import raised_priority
    from planner.bus.session import Keys, open_session
    from planner.errors import InputError
    from planner.io.scenario import load_scenario, system_from_scenario

    scn = load_scenario(scenario)
    system = system_from_scenario(scn)
    if name not in system.robot_names:
        raise InputError(
            f"unknown robot {name!r}; the scenario has {', '.join(system.robot_names)}", "--name"
        )
    if state_rate < 100:
        raise InputError(f"must be >= 100 Hz, got {state_rate:g}", "--state-rate")
    r = system.robot(name)
    laser = scn.model.system.laser
    gate = laser.gate
    emission = (Emission.from_laser(laser, spot_gain(system, name))
                if gate is not None and gate.robot == name else None)  # fmt: skip
    gate_output = None if emission is None else emission.gate_output
    backend_obj: Any
    if backend == RobotBackendName.sim:
        from drivers.robot.servo_lag import ServoSettings
        from drivers.robot.sim import SimRobot

        servo = ServoSettings(lookahead, gain) if servo_lag else None
        backend_obj = SimRobot(r.joint_names, r.home, r.limits, rate=rate, servo=servo)
    else:
        from drivers.robot.ur import URRobot

        if gate is None:
            raise InputError("the ur backend needs a laser gate (a laser is never "
                             "'always on' on real hardware)", "laser.gate")  # fmt: skip
        if not require_planner:
            raise InputError(
                "the ur backend always requires a live planner", "--no-require-planner"
            )
        if not host:
            raise InputError("the ur backend needs the controller's address", "--host")
        backend_obj = URRobot(
            host,
            r.joint_names,
            r.limits,
            robot=name,
            realtime=realtime,
            rate=rate,
            lookahead_time=lookahead,
            gain=gain,
            watchdog_hz=watchdog_hz,
            gate_output=gate_output,
            aim_output=None if emission is None else emission.aim_output,
        )
    events.configure(name)
    with raised_priority() as got:  # Zenoh's threads receive the heartbeat: they inherit it
        session = open_session(listen=listen, endpoint=endpoint, config_file=zenoh_config)
    node = RobotNode(
        session,
        Keys(prefix),
        name,
        backend_obj,
        r.limits,
        state_rate=state_rate,
        start_tolerance=start_tolerance,
        require_planner=require_planner,
        emission=emission,
        chain=tuple(system.robot_names) if gate_output is not None else (),
        realtime=True,
    )
    ros = None
    if ros2:
        from planner.ros2.bridge import Parts

        ros = _ros2(system, None, Parts.robot(name, gate=emission is not None), ros_domain,
                    prefix, endpoint, zenoh_config)  # fmt: skip
    _run(node, session, f"{name}: {backend.value} robot driver up (prefix {prefix}; "
                        f"bus {got.note})", ros)  # fmt: skip


# long: a typer command: 17 options declared in its signature (25 lines); its code is 43 lines
@app.command("camera")
def camera(
    backend: CameraBackendName = CAMERA_BACKEND,
    scenario: Path = SCENARIO,
    endpoint: str | None = ENDPOINT,
    zenoh_config: Path | None = ZCONFIG,
    prefix: str = PREFIX,
    listen: bool = LISTEN,
    spot_rate: float = typer.Option(30.0, "--spot-rate", help="camera/spot rate, Hz."),
    points_rate: float = typer.Option(15.0, "--points-rate", help="camera/points rate, Hz."),
    stride: int = typer.Option(
        1, "--stride", help="sim: use every n-th pixel (1 = full 848 x 480)."
    ),
    seed: int | None = typer.Option(None, "--seed", help="sim: noise seed."),
    serial: str | None = typer.Option(None, "--serial", help="realsense: device serial number."),
    file: Path | None = RECORDING,
    frame_timeout: float = typer.Option(
        5.0, "--frame-timeout", help="realsense: longest wait for a frameset, s (then restart)."
    ),
    exposure: float = typer.Option(
        150.0, "--exposure", help="realsense: manual colour exposure, us (0: auto exposure)."
    ),
    record: Path | None = DB3_RECORD,
    ros2: bool = ROS2,
    ros_domain: int = ROS_DOMAIN,
) -> None:
    """Run a camera driver: point cloud and laser spot. With --ros2 the cloud is on ROS 2 too
    (/camera/points, sensor_msgs/PointCloud2; node beamrelay_camera)."""
    from drivers.camera.node import CameraNode
    from planner.bus.session import Keys, open_session
    from planner.cli.ros2 import check_domain
    from planner.errors import InputError
    from planner.io.scenario import load_scenario, scene_objects, system_from_scenario

    if ros2:
        check_domain(ros_domain)
    if stride < 1:
        raise InputError(f"must be >= 1, got {stride}", "--stride")
    scn = load_scenario(scenario)
    source: Any
    if backend == CameraBackendName.sim:
        from drivers.camera.sim import SimCamera

        source = SimCamera(
            system_from_scenario(scn, truth=True), scene_objects(scn), stride=stride, seed=seed,
            gated=scn.model.system.laser.gate is not None,
        )  # fmt: skip
    else:
        from drivers.camera.realsense import RealSenseCamera

        if file is not None and not file.is_file():
            raise InputError("recording not found", f"--file {file}")
        if not 0.05 <= frame_timeout <= 60:
            raise InputError(f"must be in [0.05, 60] s, got {frame_timeout:g}", "--frame-timeout")
        if not 0 <= exposure <= 165000:
            raise InputError(f"must be in [0, 165000] us, got {exposure:g}", "--exposure")
        if record is not None and (file is not None or record.suffix != ".db3"):
            raise InputError("records a live device to a *.db3 file", f"--record {record}")
        source = RealSenseCamera(
            serial=serial, file=file, timeout_ms=round(1e3 * frame_timeout),
            exposure_us=exposure or None, record_to=record,
        )  # fmt: skip
    session = open_session(listen=listen, endpoint=endpoint, config_file=zenoh_config)
    node = CameraNode(session, Keys(prefix), source, spot_rate=spot_rate, points_rate=points_rate)
    ros = None
    if ros2:
        from planner.ros2.bridge import Parts

        ros = _ros2(system_from_scenario(scn), None, Parts.camera(), ros_domain, prefix,
                    endpoint, zenoh_config)  # fmt: skip
    _run(node, session, f"camera: {backend.value} driver up (prefix {prefix})", ros)


@app.command("tracker")
def tracker(
    scenario: Path = SCENARIO,
    endpoint: str | None = ENDPOINT,
    zenoh_config: Path | None = ZCONFIG,
    prefix: str = PREFIX,
    listen: bool = LISTEN,
    rate: float = typer.Option(30.0, "--rate", help="Frames per second, Hz."),
    latency: float = typer.Option(0.02, "--latency", help="Capture -> message delay, s."),
    seed: int | None = typer.Option(None, "--seed", help="Noise seed."),
) -> None:
    """Run the simulated marker tracker: the scenario's targets on moving objects."""
    from drivers.camera.tracker import SimTracker, TrackerNode
    from planner.bus.session import Keys, open_session
    from planner.errors import InputError
    from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
    from planner.io.scenario import targets_from_scenario as targets_of
    from planner.model.scene import tracked_objects

    if not 1.0 <= rate <= 200.0:
        raise InputError(f"must be in [1, 200] Hz, got {rate:g}", "--rate")
    if not 0.0 <= latency < 1.0 / rate:
        raise InputError(
            f"must be in [0, {1 / rate:g}) s (one frame), got {latency:g}", "--latency"
        )
    scn = load_scenario(scenario)
    truth = system_from_scenario(scn, truth=True)
    if truth.camera is None:
        raise InputError("the tracker needs system.camera in the scenario", "system.camera")
    t = targets_of(scn, system_from_scenario(scn))
    objects = tracked_objects(scene_objects(scn), t.points, t.normals)
    if not objects:
        raise InputError("no targets.points lie on a scene object with a motion", "targets")
    source = SimTracker(objects, truth.camera.world_T_camera, truth.camera.intrinsics.fx, seed)
    session = open_session(listen=listen, endpoint=endpoint, config_file=zenoh_config)
    node = TrackerNode(session, Keys(prefix), source, rate=rate, latency=latency)
    names = ", ".join(o.item.name for o in objects)
    _run(node, session, f"tracker: {names} on {Keys(prefix).target_stream} (prefix {prefix})")


@app.command("bench")
def bench(
    seconds: float = typer.Option(5.0, "--seconds", help="Flood duration, s."),
    samples: int = typer.Option(8900, "--samples", help="Samples per flood trajectory."),
    rate: float = typer.Option(10.0, "--rate", help="Flood trajectories per second."),
    quiet: float = typer.Option(3.0, "--quiet", help="Quiet measurement before the flood, s."),
    backend: RobotBackendName = typer.Option(  # noqa: B008
        RobotBackendName.sim, "--backend", help="sim, or ur on the simulated controller."
    ),
    realtime: bool = typer.Option(False, "--realtime", help="ur: SCHED_FIFO control loop."),
    stream: bool = typer.Option(
        False, "--stream", help="sim: a 500 Hz setpoint stream instead of the flood."
    ),
    garbage: float = typer.Option(
        0.0, "--garbage", help="--stream: also this many bad bodies per second on the key."
    ),
) -> None:
    """Control-loop jitter of a robot driver, quiet and under a trajectory flood (or while
    it follows a setpoint stream)."""
    from drivers.bench import flood_jitter
    from planner.errors import InputError

    if not 0 < seconds <= 600 or not 0 < quiet <= 600:
        raise InputError("must be in (0, 600] s", "--seconds/--quiet")
    if not 0 <= garbage <= 1000:
        raise InputError(f"must be in [0, 1000] per s, got {garbage:g}", "--garbage")
    if stream:
        from drivers.stream_bench import stream_jitter

        r = stream_jitter(seconds=seconds, quiet=quiet, garbage=garbage)
        typer.echo(f"quiet: {r['quiet'].line()}")
        typer.echo(f"streaming ({r['sent']} setpoints sent, {r['received']} bodies received, "
                   f"{r['rejected']} rejected): {r['streaming'].line()}")  # fmt: skip
        typer.echo(f"stream: {r['stream']}")
        return
    if not 2 <= samples <= 10_000:
        raise InputError(f"must be in [2, 10000] (bodies under 4 MiB), got {samples}", "--samples")
    if not 0 < rate <= 100:
        raise InputError(f"must be in (0, 100] per s, got {rate:g}", "--rate")
    r = flood_jitter(seconds=seconds, samples=samples, rate=rate, quiet=quiet,
                     backend=backend.value, realtime=realtime)  # fmt: skip
    typer.echo(f"backend {r['backend']}" + ("" if r["watchdog_trips"] is None
               else f" (simulated controller, RTDE watchdog trips: {r['watchdog_trips']})"))  # fmt: skip
    typer.echo(f"quiet: {r['quiet'].line()}")
    typer.echo(
        f"flood ({r['sent']} x {r['bytes'] / 1e6:.1f} MB at {rate:g}/s, {r['checked']} checked, "
        f"{r['superseded']} superseded): {r['flood'].line()}"
    )


def _ros2(
    system: Any, scene: Any, parts: Any, domain: int, prefix: str, endpoint: Any, config: Any
) -> Any:
    """A starter of the process's own ROS 2 bridge (:func:`planner.ros2.bridge.start_in_process`),
    called by :func:`_run` once the node is up (on the bus the node is on)."""
    from planner.bus.session import Keys
    from planner.ros2.bridge import start_in_process

    return lambda: start_in_process(system, scene, parts, domain=domain, keys=Keys(prefix),
                                    endpoint=endpoint, zenoh_config=config)  # fmt: skip


def _run(node: Any, session: Any, banner: str, ros: Any = None) -> None:
    """Start a node, block until Ctrl-C / SIGTERM, then stop it and close the session. ``ros``
    starts the process's ROS 2 bridge after the node (it is closed before the node stops)."""

    def _terminate(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _terminate)
    bridge = None
    try:
        node.start()
        if ros is not None:
            bridge = ros()
            typer.echo(f"ROS 2: {len(bridge.bridge.topics)} topics", err=True)
        typer.echo(banner, err=True)
        node.wait()
    except KeyboardInterrupt:
        pass
    finally:
        if bridge is not None:
            bridge.close()
        node.stop()
        session.close()
    if node.failure is not None:
        typer.echo(f"error: {node.failure}", err=True)
        raise typer.Exit(1)
