"""``beamrelay serve``, ``beamrelay up`` and ``beamrelay request``: the running system.

Light imports only at module level (``beamrelay --help`` stays instant); Zenoh, CasADi and
the planner are imported inside the commands.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from planner.cli.args import parse_xyz, stop_on_signals, wait_until_set
from planner.errors import BeamrelayError, InputError
from planner.model.status import Status

EndpointOpt = Annotated[
    str | None,
    typer.Option(
        "--endpoint",
        help="Bus endpoint (default tcp/127.0.0.1:7447 or $BEAMRELAY_ZENOH_ENDPOINT).",
    ),
]
#: seconds per target added to --timeout for a closed-loop reply (it comes after the motion)
CLOSED_LOOP_SECONDS_PER_TARGET = 15.0
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
ZENOH_CONFIG_HELP = (
    "Zenoh config file (JSON5): user/password authentication, access control, TLS, routers; "
    "it replaces the default peer/loopback settings, the bus endpoint still comes from "
    "--endpoint unless the file names its own. Examples: scenarios/zenoh/."
)
ZenohConfigOpt = Annotated[
    Path | None, typer.Option("--zenoh-config", help=ZENOH_CONFIG_HELP, dir_okay=False)
]


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
) -> None:
    """Run the planner node until Ctrl-C / SIGTERM.

    With --online-calibration FILE, spots the camera measures at rest refine the laser line
    and mirror plane in the background; each accepted version is written to FILE (a
    calibration YAML a scenario can include), published on <prefix>/calibration and used for
    later plans. An existing FILE not written by the online refinement is never overwritten.

    Exits 1 if the node fails (its worker thread died or stayed busy on one request beyond
    its allowance): the heartbeat has stopped and the liveliness token is gone by then, so
    robots brake and a supervisor (``beamrelay up``) restarts the planner.
    """
    import os
    import threading

    from planner.service.bus import Keys, open_session
    from planner.service.node import BusAddress, PlannerNode, handler_from_scenario

    handler = handler_from_scenario(scenario)
    online = None
    if online_calibration is not None:
        online = online_calibrator(scenario, online_calibration, handler.system)
    session = open_session(listen=not connect, endpoint=endpoint, config_file=zenoh_config)
    node = PlannerNode(handler, session, Keys(prefix), bus=BusAddress(endpoint, zenoh_config),
                       online=online)  # fmt: skip
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
    typer.echo(f"planner ready: {prefix}/plan, robots {names}, session {node.session_id}")
    try:
        wait_until_set(stop)
    finally:
        node.close()
        session.close()
        typer.echo(f"planner stopped after {node.served} requests")
    if node.failed is not None:
        raise typer.Exit(1)


def online_calibrator(scenario: Path, out: Path, system: Any) -> Any:
    """The node's :class:`~planner.service.online.OnlineCalibrator` writing ``out`` (InputError
    if ``out`` is the scenario or a file the online refinement did not write)."""
    from planner.service.handler import handler_from_scenario
    from planner.service.online import OnlineCalibrator, check_output_file

    path = check_output_file(out, scenario)
    return OnlineCalibrator(system, path, rebuild=lambda f: handler_from_scenario(scenario, (f,)))


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
            "tracker, console .json5, e.g. scenarios/zenoh/roles): each child joins with its "
            "role's identity, up itself with the console's. Replaces --zenoh-config.",
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
    from planner.cli.ros2 import check_domain
    from planner.console.address import DEFAULT_HOST, check_free, check_port
    from planner.service.up import run_up

    if console:
        check_port(console_port, "--console-port")
        check_free(DEFAULT_HOST, console_port, "--console-port")

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
        online_calibration=online_calibration,
        zenoh_roles=zenoh_roles,
        ros_domain=check_domain(ros_domain) if ros2 else None,
    )


def request(
    points: Annotated[
        list[str], typer.Option("--points", help="X,Y,Z target in metres (repeat for more).")
    ],
    frame: Annotated[str, typer.Option(help="world or camera.")] = "world",
    path: Annotated[bool, typer.Option("--path", help="Sweep the points as one path.")] = False,
    execute: Annotated[bool, typer.Option("--execute", help="Move the robots.")] = False,
    normals: Annotated[
        list[str] | None, typer.Option("--normals", help="NX,NY,NZ per point (optional).")
    ] = None,
    closed_loop: Annotated[
        bool,
        typer.Option(
            "--closed-loop",
            help="With --execute: correct each target from the camera's measured spot, then "
            "dwell with the laser on (the reply comes after the motion; --timeout is extended "
            f"by {CLOSED_LOOP_SECONDS_PER_TARGET:g} s per target).",
        ),
    ] = False,
    dwell: Annotated[
        float | None, typer.Option("--dwell", help="Laser-on dwell per target (s).")
    ] = None,
    tolerance: Annotated[
        float | None,
        typer.Option("--tolerance", help="Closed-loop measured-error tolerance (m; default 3e-4)."),
    ] = None,
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the reply.")] = 10.0,
    track: Annotated[
        str | None,
        typer.Option(
            "--track",
            help="Follow the target stream of this id (the first point is"
            " its first estimate; moves the robots).",
        ),
    ] = None,
    duration: Annotated[
        float | None, typer.Option("--duration", help="--track: seconds to follow it.")
    ] = None,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    zenoh_config: ZenohConfigOpt = None,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="End with one JSON object (id, execution, n_ok, measured errors in m, per "
            "target figures) on the last line of standard output; the table goes to stderr.",
        ),
    ] = False,
) -> None:
    """Send one TargetRequest, print the plan summary (and the measured spots if executing).

    Exits 1 when a target could not be solved, the robot drivers rejected the trajectory or
    (closed loop) a target did not converge to the tolerance.
    """
    import json

    from rich.console import Console

    from planner.service.client import (
        PlanClient,
        RequestError,
        make_request,
        request_summary,
        world_T_camera_of,
    )

    if frame not in ("world", "camera"):
        raise InputError(f"--frame {frame!r}: expected world or camera")
    if not timeout > 0:
        raise InputError(f"--timeout {timeout}: expected a positive number of seconds")
    pts = [parse_xyz(p, "--points") for p in points]
    nrm = [parse_xyz(n, "--normals") for n in normals] if normals else None
    if nrm is not None and len(nrm) != len(pts):
        raise InputError(f"--normals: {len(nrm)} given for {len(pts)} points")
    if dwell is not None and not (0 <= dwell <= 600):
        raise InputError(f"--dwell {dwell}: expected 0 to 600 s")
    if tolerance is not None and not (0 < tolerance <= 0.05):
        raise InputError(f"--tolerance {tolerance}: expected 0 < m <= 0.05 (metres, not mm)")
    if closed_loop and not execute:
        raise InputError(
            "--closed-loop needs --execute (the spot is measured on the moving robots)"
        )
    req = make_request(pts, frame=frame, normals=nrm, path=path, execute=execute,
                       closed_loop=closed_loop, dwell=dwell, tolerance=tolerance)  # fmt: skip
    reply_timeout = timeout + (CLOSED_LOOP_SECONDS_PER_TARGET * len(pts) if closed_loop else 0.0)
    if track is not None:
        if closed_loop:
            raise InputError("--closed-loop: not with --track (tracking gates the laser itself)")
        _track_request(req, track, duration, path, timeout, (endpoint, prefix, zenoh_config),
                       as_json)  # fmt: skip
        return
    if duration is not None:
        raise InputError("--duration: only with --track")
    console = Console(stderr=as_json)
    client = PlanClient(
        endpoint=endpoint, prefix=prefix, zenoh_config=zenoh_config, connect_timeout=timeout
    )
    with client:
        try:
            if execute:
                client.watch()
            # a query sent before the bus has routed to the planner gets no reply: wait for
            # its liveliness token first (a missing planner is then named as such)
            if not client.wait_for_node("planner", timeout):
                raise RequestError(f"no planner on the bus ({prefix}/alive/planner) within "
                                   f"{timeout:g} s")  # fmt: skip
            if execute:
                plan, spots = client.execute(req, reply_timeout)
            else:
                plan, spots = client.request(req, timeout), None
        except RequestError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from exc
    if world_T_camera_of(plan) is None:
        spots = None  # nothing can be measured: no column for it
    print_summary(console, plan, spots)
    rejected = execute and plan.get("execution") != "accepted"
    if execute:
        reason = plan.get("execution_reason") or "no verdict in the reply"
        console.print(f"execution: REJECTED: {reason}" if rejected else "execution: accepted",
                      style="bold red" if rejected else None, markup=False,
                      soft_wrap=True)  # fmt: skip
    servo_rows = (plan.get("closed_loop") or {}).get("targets") or []
    if servo_rows:
        print_closed_loop(console, plan)
    if as_json:
        print(json.dumps(request_summary(plan, spots)))
    unconverged = any(r.get("status") != "converged" for r in servo_rows)
    if rejected or unconverged or any(s["status"] != Status.OK for s in plan["solutions"]):
        raise typer.Exit(1)


def print_closed_loop(console: object, plan: dict) -> None:
    """One line per closed-loop target (status, measured error before/after, iterations,
    frames, time, dwell) and the totals."""
    from rich.console import Console

    assert isinstance(console, Console)

    def mm(x: float | None) -> str:
        return "-" if x is None else f"{1e3 * x:.3f} mm"

    cl = plan["closed_loop"]
    for r in cl["targets"]:
        why = f" ({r['reason']}: {r.get('detail')})" if r.get("reason") else ""
        console.print(f"closed loop {r['id']}: {r['status']}{why}; measured error "
                      f"{mm(r.get('measured_error_before'))} -> {mm(r.get('measured_error_after'))}"
                      f", {r.get('iterations', 0)} corrections, {r.get('frames', 0)} frames, "
                      f"{r.get('time', 0.0):.2f} s, dwell {r.get('dwell', 0.0):.2f} s"
                      f"{'' if r.get('treated', True) else ' (not treated)'}",
                      markup=False, soft_wrap=True)  # fmt: skip
    x = plan["metrics"].get("extra", {})
    console.print(f"closed loop: {x.get('closed_loop_converged', 0):.0f}/{len(cl['targets'])} "
                  f"within {mm(cl['tolerance'])}; measured error median "
                  f"{mm(x.get('measured_error_before_median'))} -> "
                  f"{mm(x.get('measured_error_median'))}, max "
                  f"{mm(x.get('measured_error_before_max'))} -> {mm(x.get('measured_error_max'))}",
                  markup=False, soft_wrap=True)  # fmt: skip


def _track_request(
    req: dict, stream: str, duration: float | None, path: bool, timeout: float,
    bus: tuple, as_json: bool,
) -> None:  # fmt: skip
    """Send a ``mode: track`` request and, with a duration, wait for the session's summary
    (published on ``<prefix>/plans``); prints it (``--json``: as one JSON object)."""
    import json
    import threading

    from planner.service.client import PlanClient, RequestError

    if path:
        raise InputError("--track follows one moving target: not with --path")
    if duration is not None and not 0 < duration <= 3600:
        raise InputError(f"--duration {duration}: expected (0, 3600] s")
    req.update(id=stream, mode="track", execute=True)
    if duration is not None:
        req["duration"] = duration
    endpoint, prefix, zenoh_config = bus
    summaries: list[dict] = []
    got = threading.Event()

    def on_plan(sample: object) -> None:
        body = json.loads(sample.payload.to_bytes())  # type: ignore[attr-defined]
        if body.get("schema") == "beamrelay.track/1" and body.get("id") == stream:
            summaries.append(body)
            got.set()

    client = PlanClient(endpoint=endpoint, prefix=prefix, zenoh_config=zenoh_config,
                        connect_timeout=timeout)  # fmt: skip
    with client:
        sub = client.session.declare_subscriber(f"{prefix}/plans", on_plan)
        try:
            if not client.wait_for_node("planner", timeout):
                raise RequestError(f"no planner on the bus ({prefix}/alive/planner)")
            reply = client.request(req, timeout)
            typer.echo(f"tracking {stream!r}: {reply.get('execution')}", err=as_json)
            if duration is not None and not got.wait(duration + timeout):
                raise RequestError(
                    f"no summary of tracking {stream!r} within {duration + timeout:g} s"
                )
        except RequestError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from exc
        finally:
            sub.undeclare()
    if summaries:
        s = summaries[-1]
        if as_json:
            print(json.dumps(s))
        else:
            lat = s.get("latency_p99")
            typer.echo(
                f"ended: {s['ended']}; {s['frames']} frames, laser on "
                f"{100 * s['laser_on_fraction']:.0f} %"
                + ("" if lat is None else f", frame -> setpoint p99 {1e3 * lat:.2f} ms")
            )


def print_summary(console: object, plan: dict, spots: list | None) -> None:
    """A table of the plan's targets: status, planned error, and measured spot error."""
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    assert isinstance(console, Console)
    table = Table(title=f"plan: {len(plan['targets'])} targets, robots {', '.join(plan['robots'])}")
    for col in ("id", "target x y z \\[m]", "status", "planned error \\[mm]", "solve \\[ms]"):
        table.add_column(col)
    if spots is not None:
        table.add_column("measured error \\[mm]")
    for k, (tgt, sol) in enumerate(zip(plan["targets"], plan["solutions"], strict=True)):
        row = [
            str(tgt["id"]),
            " ".join(f"{x:+.4f}" for x in tgt["p"]),
            sol["status"] if sol["status"] == Status.OK else f"[red]{sol['reason']}[/]",
            f"{1e3 * sol['error']:.2e}" if sol.get("error") is not None else "-",
            f"{1e3 * sol['solve_time']:.2f}" if sol.get("solve_time") is not None else "-",
        ]
        if spots is not None:
            s = spots[k]
            err = None if s is None else float(np.linalg.norm(s - np.asarray(tgt["p"])))
            row.append("not seen" if err is None else f"{1e3 * err:.2f}")
        table.add_row(*row)
    console.print(table)
    m = plan["metrics"]
    traj = f"trajectory {m['duration']:.2f} s" if m.get("duration") else "no trajectory"
    console.print(f"solved {m['n_ok']}/{m['n_targets']}; {traj}")
    if spots is not None:
        errs = [
            float(np.linalg.norm(s - np.asarray(t["p"])))
            for s, t in zip(spots, plan["targets"], strict=True)
            if s is not None
        ]
        if len(errs) < sum(s["status"] == Status.OK for s in plan["solutions"]):
            console.print(
                "spots are measured while the robots rest on a target: targets passed without "
                "a pause (scenario trajectory.dwell = 0) or hidden from the camera are not seen"
            )
        if errs:
            console.print(
                f"measured spot error: median {1e3 * np.median(errs):.2f} mm, "
                f"max {1e3 * max(errs):.2f} mm over {len(errs)} targets"
            )
