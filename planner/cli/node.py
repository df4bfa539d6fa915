"""``beamrelay serve``, ``beamrelay up`` and ``beamrelay request``: the running system.

Light imports only at module level (``beamrelay --help`` stays instant); Zenoh, CasADi and
the planner are imported inside the commands.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from planner.cli.args import parse_xyz
from planner.errors import BeamrelayError, InputError
from planner.model.status import Status

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
    zenoh_config: Annotated[
        Path | None, typer.Option("--zenoh-config", help="Zenoh config file (routers, TLS, ACL).")
    ] = None,
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
    import signal
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
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    def on_fatal(reason: str) -> None:
        typer.echo(f"error: planner node failed: {reason}; exiting", err=True)
        stop.set()
        # last resort: if the orderly shutdown below hangs, leave anyway
        last_resort = threading.Timer(FATAL_EXIT_GRACE, os._exit, args=(1,))
        last_resort.daemon = True
        last_resort.start()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
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
        while not stop.wait(0.2):
            pass
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
    host: Annotated[
        list[str] | None,
        typer.Option(
            "--host",
            help="ur backend: NAME=ADDRESS of each robot's controller (repeat per robot).",
        ),
    ] = None,
    online_calibration: OnlineOpt = None,
) -> None:
    """Start planner + camera + one robot driver per robot, supervised, until Ctrl-C.

    --zenoh-config is used by up itself and passed on to every child."""
    from planner.service.up import run_up

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
        online_calibration=online_calibration,
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
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the reply.")] = 10.0,
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

    Exits 1 when a target could not be solved or the robot drivers rejected the trajectory.
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
    req = make_request(pts, frame=frame, normals=nrm, path=path, execute=execute)
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
                plan, spots = client.execute(req, timeout)
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
    if as_json:
        print(json.dumps(request_summary(plan, spots)))
    if rejected or any(s["status"] != Status.OK for s in plan["solutions"]):
        raise typer.Exit(1)


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
