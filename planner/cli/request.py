"""``beamrelay request``: the client of the running system (one TargetRequest, its plan
summary, the measured spots and the closed-loop figures; a tracking session's summary).

Exit status: 0 the request was answered and everything it asked for ran to its end; 1 a
target failed, the drivers rejected the trajectory, a motion or tracking session was
interrupted (a lost heartbeat, a stale setpoint stream, a stop), or a closed-loop target
did not converge; 2 bad input or a bus problem (no planner on the bus within --timeout).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from planner.cli.args import parse_xyz
from planner.cli.node import EndpointOpt, PrefixOpt, ZenohConfigOpt
from planner.errors import InputError
from planner.model.status import Status
from schemas.messages import TRACK_SCHEMA

if TYPE_CHECKING:
    from planner.io.plan import Plan

#: seconds per target added to --timeout for a closed-loop reply (it comes after the motion)
CLOSED_LOOP_SECONDS_PER_TARGET = 15.0


# long: a typer command: 15 options declared in its signature (52 lines); the request, its wait and its tables follow in order
def request(
    points: Annotated[
        list[str],
        typer.Option("--points", metavar="X,Y,Z", help="Target in metres (repeat for more)."),
    ],
    frame: Annotated[str, typer.Option(help="world or camera.")] = "world",
    path: Annotated[bool, typer.Option("--path", help="Sweep the points as one path.")] = False,
    execute: Annotated[bool, typer.Option("--execute", help="Move the robots.")] = False,
    normals: Annotated[
        list[str] | None,
        typer.Option("--normals", metavar="NX,NY,NZ", help="Surface normal per point (optional)."),
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

    Exits 1 when a target could not be solved, the robot drivers rejected the trajectory, the
    motion or tracking session was interrupted (a lost heartbeat, a stale setpoint stream, a
    stop), or (closed loop) a target did not converge to the tolerance; exits 2 on bad input
    or when no planner is on the bus within --timeout.
    """
    import json

    from rich.console import Console

    from planner.io.plan import Verdict
    from planner.service.client import (
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
    client = connect_to_planner(endpoint, prefix, zenoh_config, timeout)
    with client:
        try:
            if execute:
                plan, spots = client.execute_plan(req, reply_timeout)
            else:
                plan, spots = client.plan(req, timeout), None
        except RequestError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from exc
        interruption = client.interruption
    if world_T_camera_of(plan) is None:
        spots = None  # nothing can be measured: no column for it
    print_summary(console, plan, spots)
    for text in plan.warnings or ():
        console.print(f"warning: {text}", style="yellow", markup=False, soft_wrap=True)
    rejected = execute and plan.execution is not Verdict.ACCEPTED
    if execute:
        reason = plan.execution_reason or "no verdict in the reply"
        console.print(f"execution: REJECTED: {reason}" if rejected else "execution: accepted",
                      style="bold red" if rejected else None, markup=False,
                      soft_wrap=True)  # fmt: skip
    if interruption is not None:
        console.print(f"execution: INTERRUPTED: {interruption}", style="bold red",
                      markup=False, soft_wrap=True)  # fmt: skip
    servo_rows = () if plan.closed_loop is None else plan.closed_loop.targets
    if servo_rows:
        print_closed_loop(console, plan)
    if as_json:
        print(json.dumps(request_summary(plan, spots)))
    unconverged = not all(r.converged for r in servo_rows)
    if (
        rejected
        or unconverged
        or interruption is not None
        or any(s.status is not Status.OK for s in plan.solutions)
    ):
        raise typer.Exit(1)


def print_closed_loop(console: object, plan: Plan) -> None:
    """One line per closed-loop target (status, measured error before/after, iterations,
    frames, time, dwell) and the totals."""
    from rich.console import Console

    assert isinstance(console, Console)

    def mm(x: float | None) -> str:
        return "-" if x is None else f"{1e3 * x:.3f} mm"

    cl = plan.closed_loop
    assert cl is not None
    for r in cl.targets:
        why = f" ({r.reason}: {r.detail})" if r.reason is not None else ""
        s = r.servo
        before, after = (None, None) if s is None else (s.error_before, s.error_after)
        steps, frames, seconds = (0, 0, 0.0) if s is None else (s.iterations, s.frames, s.time)
        console.print(f"closed loop {r.id}: {r.status}{why}; measured error {mm(before)} -> "
                      f"{mm(after)}, {steps} corrections, {frames} frames, {seconds:.2f} s, "
                      f"dwell {r.dwell:.2f} s{' (not treated)' if r.treated is False else ''}",
                      markup=False, soft_wrap=True)  # fmt: skip
    x = plan.metrics.extra
    console.print(f"closed loop: {cl.converged}/{len(cl.targets)} "
                  f"within {mm(cl.tolerance)}; measured error median "
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

    from planner.service.client import RequestError

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
        if body.get("schema") == TRACK_SCHEMA and body.get("id") == stream:
            summaries.append(body)
            got.set()

    client = connect_to_planner(endpoint, prefix, zenoh_config, timeout)
    with client:
        sub = client.session.declare_subscriber(f"{prefix}/plans", on_plan)
        try:
            reply = client.plan(req, timeout)
            typer.echo(f"tracking {stream!r}: {reply.execution}", err=as_json)
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
        if not s.get("completed", False):  # ended before its duration: a fault, a stop
            typer.echo(f"error: tracking {stream!r} interrupted after {s['duration']:.2f} s: "
                       f"{s['ended']}", err=True)  # fmt: skip
            raise typer.Exit(1)


def connect_to_planner(endpoint: str | None, prefix: str, zenoh_config: Path | None,
                       timeout: float) -> Any:  # fmt: skip
    """A :class:`~planner.service.client.PlanClient` on a bus where the planner is alive,
    within ``timeout`` s in all (opening the session included). No planner by then is a bus
    problem: InputError (exit 2, one line)."""
    import time

    from planner.service.client import PlanClient

    t0 = time.monotonic()
    client = PlanClient(endpoint=endpoint, prefix=prefix, zenoh_config=zenoh_config,
                        connect_timeout=timeout)  # fmt: skip
    # a query sent before the bus has routed to the planner gets no reply: wait for its
    # liveliness token first (a missing planner is then named as such)
    if not client.wait_for_node("planner", max(0.0, timeout - (time.monotonic() - t0))):
        client.close()
        where = endpoint or "the default endpoint"
        raise InputError(f"no planner on the bus ({prefix}/alive/planner via {where}) within "
                         f"{timeout:g} s: is 'beamrelay up' or 'beamrelay serve' running?")  # fmt: skip
    return client


def print_summary(console: object, plan: Plan, spots: list | None) -> None:
    """A table of the plan's targets: status, planned error, and measured spot error."""
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    assert isinstance(console, Console)
    table = Table(title=f"plan: {len(plan.targets)} targets, robots {', '.join(plan.robots)}")
    for col in ("id", "target x y z \\[m]", "status", "planned error \\[mm]", "solve \\[ms]"):
        table.add_column(col)
    if spots is not None:
        table.add_column("measured error \\[mm]")
    for k, sol in enumerate(plan.solutions):
        p = plan.targets.p[k]
        row = [
            str(plan.targets.ids[k]),
            " ".join(f"{x:+.4f}" for x in p),
            str(sol.status) if sol.status is Status.OK else f"[red]{sol.reason}[/]",
            f"{1e3 * sol.error:.2e}" if sol.error is not None else "-",
            f"{1e3 * sol.solve_time:.2f}",
        ]
        if spots is not None:
            s = spots[k]
            err = None if s is None else float(np.linalg.norm(s - p))
            row.append("not seen" if err is None else f"{1e3 * err:.2f}")
        table.add_row(*row)
    console.print(table)
    m = plan.metrics
    traj = f"trajectory {m.duration:.2f} s" if m.duration else "no trajectory"
    console.print(f"solved {m.n_ok}/{m.n_targets}; {traj}")
    if spots is not None:
        errs = [
            float(np.linalg.norm(s - p))
            for s, p in zip(spots, plan.targets.p, strict=True)
            if s is not None
        ]
        if len(errs) < sum(s.status is Status.OK for s in plan.solutions):
            console.print(
                "spots are measured while the robots rest on a target: targets passed without "
                "a pause (scenario trajectory.dwell = 0) or hidden from the camera are not seen"
            )
        if errs:
            console.print(
                f"measured spot error: median {1e3 * np.median(errs):.2f} mm, "
                f"max {1e3 * max(errs):.2f} mm over {len(errs)} targets"
            )
