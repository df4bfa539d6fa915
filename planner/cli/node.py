"""``beamrelay serve`` and ``beamrelay up``: the running system (``request``, its client, is
in :mod:`planner.cli.request`).

Light imports only at module level (``beamrelay --help`` stays instant); Zenoh, CasADi and
the planner are imported inside the commands.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from planner.cli.args import check_domain, stop_on_signals, wait_until_set
from planner.errors import BeamrelayError, InputError

EndpointOpt = Annotated[
    str | None,
    typer.Option(
        "--endpoint",
        help="Bus endpoint (default tcp/127.0.0.1:7447 or $BEAMRELAY_ZENOH_ENDPOINT).",
    ),
]
#: seconds a failed planner node gets to shut down in order before the process is ended
FATAL_EXIT_GRACE = 10.0

OnlineOpt = Annotated[
    Path | None,
    typer.Option(
        "--online-calibration",
        help="Refine the calibration online from measured spots; write it to this file.",
        dir_okay=False,
    ),
]
PrefixOpt = Annotated[str, typer.Option("--prefix", help="Key-expression namespace prefix.")]
Ros2Opt = Annotated[
    bool,
    typer.Option(
        "--ros2",
        help="Also publish this process's ROS 2 topics (rmw_zenoh key expressions), from a"
        " thread and Zenoh session of their own.",
    ),
]
RosDomainOpt = Annotated[
    int, typer.Option("--ros-domain", help="ROS_DOMAIN_ID of the ROS 2 topics (0-232).")
]
ZENOH_CONFIG_HELP = (
    "Zenoh config file (JSON5): user/password authentication, access control, TLS, routers; "
    "it replaces the default peer/loopback settings, the bus endpoint still comes from "
    "--endpoint unless the file names its own. Examples: scenarios/zenoh/."
)
ZenohConfigOpt = Annotated[
    Path | None, typer.Option("--zenoh-config", help=ZENOH_CONFIG_HELP, dir_okay=False)
]


# long: a typer command: 8 options and a 14-line docstring; the node's set-up follows in start order
def serve(
    scenario: Annotated[
        Path, typer.Argument(help="Scenario YAML (calibrated values via include:).")
    ],
    endpoint: EndpointOpt = None,
    zenoh_config: ZenohConfigOpt = None,
    prefix: PrefixOpt = "beamrelay",
    connect: Annotated[
        bool,
        typer.Option("--connect", help="Connect to the endpoint instead of listening on it."),
    ] = False,
    online_calibration: OnlineOpt = None,
    ros2: Ros2Opt = False,
    ros_domain: RosDomainOpt = 0,
) -> None:
    """Run the planner node until Ctrl-C / SIGTERM.

    With --online-calibration FILE, spots the camera measures at rest refine the laser line
    and mirror plane in the background; each accepted version is written to FILE (a
    calibration YAML a scenario can include), published on <prefix>/calibration and used for
    later plans. An existing FILE not written by the online refinement is never overwritten.

    With --ros2 the cell's fixed frames (/tf_static), the markers (beam, mirrors, targets,
    spot) and the ROS 2 target topics are on ROS 2 too (node beamrelay_planner).

    Exits 1 if the node fails (its worker thread died or stayed busy on one request beyond
    its allowance): the heartbeat has stopped and the liveliness token is gone by then, so
    robots brake and a supervisor (``beamrelay up``) restarts the planner.
    """
    import os
    import threading

    from planner.bus import events
    from planner.bus.session import Keys, open_session
    from planner.service.node import BusAddress, PlannerNode, handler_from_scenario

    if ros2:
        check_domain(ros_domain)
    handler = handler_from_scenario(scenario)
    online = None
    if online_calibration is not None:
        online = online_calibrator(scenario, online_calibration, handler.system)
        if online.resume():  # a restart goes on with the version it had
            handler = online.rebuild(online.out_file)
            typer.echo(f"online calibration: resuming version {online.current.version} from"
                       f" {online.out_file} (remove it to start from the scenario's)", err=True)  # fmt: skip
    events.configure("planner")
    from planner.bus.priority import raised_priority

    # its Zenoh threads send the setpoints and stops: real time like a driver's (requests
    # are handed to the worker thread at once; the callbacks only decode small messages)
    with raised_priority() as got:
        session = open_session(listen=not connect, endpoint=endpoint, config_file=zenoh_config)
    typer.echo(f"planner bus {got.note}", err=True)
    node = PlannerNode(handler, session, Keys(prefix), bus=BusAddress(endpoint, zenoh_config),
                       online=online, warm_up=True)  # fmt: skip
    if online is not None:
        node.install_calibration(handler, online.current)  # plans report the resumed version
    stop = stop_on_signals()

    def on_fatal(reason: str) -> None:
        typer.echo(f"error: planner node failed: {reason}; exiting", err=True)
        stop.set()
        # last resort: if the orderly shutdown below hangs, leave anyway
        last_resort = threading.Timer(FATAL_EXIT_GRACE, os._exit, args=(1,))
        last_resort.daemon = True
        last_resort.start()

    node.on_alive_change = lambda name, up: typer.echo(
        f"{'up' if up else 'DOWN'}: {name}", err=not up
    )
    node.on_fatal = on_fatal
    try:
        node.start()
    except BeamrelayError as exc:  # the heartbeat process could not start
        session.close()
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    names = ", ".join(handler.system.robot_names)
    ros = None
    if ros2:
        from planner.io.scenario import load_scenario, scene_model
        from planner.ros2.bridge import Parts, start_in_process

        ros = start_in_process(handler.system, scene_model(load_scenario(scenario)),
                               Parts.planner(), domain=ros_domain, keys=Keys(prefix),
                               endpoint=endpoint, zenoh_config=zenoh_config)  # fmt: skip
        typer.echo(f"ROS 2: domain {ros_domain}, {len(ros.bridge.topics)} topics", err=True)
    typer.echo(f"planner ready: {prefix}/plan, robots {names}, session {node.session_id}")
    try:
        wait_until_set(stop)
    finally:
        if ros is not None:
            ros.close()
        node.close()
        session.close()
        typer.echo(f"planner stopped after {node.served} requests")
    if node.failed is not None:
        raise typer.Exit(1)


def online_calibrator(scenario: Path, out: Path, system: Any) -> Any:
    """The node's :class:`~planner.service.online.OnlineCalibrator` writing ``out`` (InputError
    if ``out`` is the scenario or a file the online refinement did not write)."""
    from planner.io.scenario import load_scenario, scene_model
    from planner.service.handler import handler_from_scenario
    from planner.service.online import OnlineCalibrator
    from planner.service.online_file import check_output_file

    path = check_output_file(out, scenario)
    return OnlineCalibrator(system, path, rebuild=lambda f: handler_from_scenario(scenario, (f,)),
                            scene=scene_model(load_scenario(scenario)))  # fmt: skip


# long: a typer command: 17 options declared in its signature (64 lines); its code is 35 lines
def up(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML.")],
    backend: Annotated[str, typer.Option(help="Robot driver backend: sim or ur.")] = "sim",
    duration: Annotated[
        float | None, typer.Option(help="Stop after this many seconds (default: Ctrl-C).")
    ] = None,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    log_dir: Annotated[
        Path | None, typer.Option("--log-dir", help="Children's logs (default: a temp dir).")
    ] = None,
    live: Annotated[bool, typer.Option(help="Show the live health table.")] = True,
    zenoh_config: ZenohConfigOpt = None,
    planner_zenoh_config: Annotated[
        Path | None,
        typer.Option(
            "--planner-zenoh-config",
            help="Zenoh config of the planner child only (its own identity on a bus with "
            "access control; default: --zenoh-config).",
            dir_okay=False,
        ),
    ] = None,
    zenoh_roles: Annotated[
        Path | None,
        typer.Option(
            "--zenoh-roles",
            help="Folder of Zenoh config files, one per role (planner, driver, camera, "
            "tracker, console, ros2 .json5, e.g. scenarios/zenoh/roles): each child joins with "
            "its role's identity, up itself with the console's. Replaces --zenoh-config.",
            file_okay=False,
        ),
    ] = None,
    host: Annotated[
        list[str] | None,
        typer.Option(
            "--host",
            help="ur backend: NAME=ADDRESS of each robot's controller (repeat per robot).",
        ),
    ] = None,
    console: Annotated[
        bool, typer.Option("--console", help="Also run the operator console (browser page).")
    ] = False,
    console_port: Annotated[
        int, typer.Option("--console-port", help="Port of the console page on 127.0.0.1.")
    ] = 8080,
    console_workdir: Annotated[
        Path | None,
        typer.Option(
            "--console-workdir",
            help="Working directory of the console's calibration wizard (beamrelay console "
            "--workdir; default: $XDG_DATA_HOME/beamrelay/console).",
        ),
    ] = None,
    online_calibration: OnlineOpt = None,
    ros2: Annotated[
        bool,
        typer.Option(
            "--ros2", help="Also publish ROS 2 topics (rmw_zenoh; beamrelay ros2 bridge)."
        ),
    ] = False,
    ros_domain: Annotated[
        int, typer.Option("--ros-domain", help="ROS_DOMAIN_ID of the ROS 2 topics (0-232).")
    ] = 0,
) -> None:
    """Start planner + camera + one robot driver per robot, supervised, until Ctrl-C.

    --zenoh-config is used by up itself and passed on to every child. With --ros2 the ROS 2
    bridge runs as one more child, in its own process (never on a control loop)."""
    from planner.console.address import DEFAULT_HOST, check_free, check_port
    from planner.console.workdir import ensure_dir
    from planner.service.up import run_up

    if console:
        check_port(console_port, "--console-port")
        check_free(DEFAULT_HOST, console_port, "--console-port")
    if console_workdir is not None:
        if not console:
            raise InputError("--console-workdir: the console's folder needs --console")
        console_workdir = ensure_dir(console_workdir, "--console-workdir")

    if backend not in ("sim", "ur"):
        raise InputError(f"--backend {backend!r}: expected sim or ur")
    if duration is not None and duration <= 0:
        raise InputError(f"--duration {duration}: expected a positive number of seconds")
    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}")
    run_up(
        scenario,
        backend=backend,
        duration=duration,
        endpoint=endpoint,
        prefix=prefix,
        log_dir=log_dir,
        live=live,
        zenoh_config=zenoh_config,
        planner_zenoh_config=planner_zenoh_config,
        hosts=host,
        console_port=console_port if console else None,
        console_workdir=console_workdir,
        online_calibration=online_calibration,
        zenoh_roles=zenoh_roles,
        ros_domain=check_domain(ros_domain) if ros2 else None,
    )
