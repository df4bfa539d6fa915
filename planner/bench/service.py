"""``beamrelay bench service``: the planner node's request -> reply latency, the rate and
jitter of a simulated robot driver's ``joint_states``, and the planner heartbeat's gaps
while it plans (heartbeat process, and a heartbeat thread for comparison).

Runs everything on a private loopback port: the planner node (:class:`planner.service.node.PlannerNode`
on the scenario's system) listens, a client session sends TargetRequests over TCP (so the
figures include Zenoh, JSON and validation on both sides, and the IK). Latency of one target
(``--n-single`` requests, one grid point each) and of 100 targets in one request. Then a
simulated arm (:class:`drivers.robot.node.RobotNode` + :class:`drivers.robot.sim.SimRobot`)
publishes joint states for ``--seconds`` s; the rate and the period jitter are measured on
the receiving side (receiver clock). Goal: single-target median <= 3 ms.
"""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.data import shipped_scenario

DEFAULT_SCENARIO = shipped_scenario("paper_n1.yaml")
GOAL_SINGLE_MS = 3.0


def _free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def stats_ms(seconds: list[float]) -> dict[str, float]:
    """Median, p95 and max (ms) of durations in seconds."""
    import numpy as np

    a = 1e3 * np.asarray(seconds)
    return {
        "median_ms": float(np.median(a)),
        "p95_ms": float(np.percentile(a, 95)),
        "max_ms": float(a.max()),
    }


def measure_latency(
    scenario: Path, n_single: int, n_batch: int, batch: int = 100
) -> dict[str, Any]:
    """Round-trip times (s) of single-target and ``batch``-target requests, plus solve rates."""
    from planner.bus.session import Keys, open_session
    from planner.io.scenario import load_scenario, targets_from_scenario
    from planner.service.client import PlanClient, make_request
    from planner.service.node import PlannerNode, handler_from_scenario

    handler = handler_from_scenario(scenario)
    points = targets_from_scenario(load_scenario(scenario), handler.system).points
    endpoint = _free_endpoint()
    hub = open_session(listen=True, endpoint=endpoint)
    node = PlannerNode(handler, hub, Keys("bench")).start()
    single, many, n_ok = [], [], 0
    try:
        with PlanClient(endpoint=endpoint, prefix="bench") as client:
            if not client.wait_for_node("planner", 10.0):
                raise RuntimeError("planner node not reachable on the private bus")
            client.request(make_request(points[:1]))  # warm-up (CasADi, JIT caches)
            for k in range(n_single):
                t0 = time.perf_counter()
                plan = client.request(make_request(points[k % len(points)][None]))
                single.append(time.perf_counter() - t0)
                n_ok += plan["metrics"]["n_ok"]
            for k in range(n_batch):
                sel = points[(k * batch + (k * batch + batch) // 7) % len(points) :][:batch]
                t0 = time.perf_counter()
                client.request(make_request(sel), timeout=60.0)
                many.append(time.perf_counter() - t0)
    finally:
        node.close()
        hub.close()
    return {
        "single": {**stats_ms(single), "n": n_single, "solved": n_ok},
        f"batch{batch}": {**stats_ms(many), "n": n_batch},
    }


def measure_joint_states(seconds: float) -> dict[str, float]:
    """Rate (Hz) and period jitter (ms) of a simulated arm's joint_states, receiver side."""
    import numpy as np

    from drivers.robot.node import RobotNode
    from drivers.robot.sim import SimRobot
    from planner.bus.session import Keys, open_session
    from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits

    endpoint = _free_endpoint()
    hub = open_session(listen=True, endpoint=endpoint)
    stamps: list[float] = []
    sub = hub.declare_subscriber(
        Keys("bench").joint_states("arm0"), lambda _s: stamps.append(time.perf_counter())
    )
    session = open_session(listen=False, endpoint=endpoint)
    limits = Limits.ur_default()
    backend = SimRobot(JOINT_NAMES_UR, np.array(DEFAULT_HOME), limits)
    driver = RobotNode(session, Keys("bench"), "arm0", backend, limits, require_planner=False)
    driver.start()
    try:
        time.sleep(1.0)  # connect and settle
        n0 = len(stamps)
        time.sleep(seconds)
        window = np.diff(np.asarray(stamps[n0:]))
    finally:
        driver.stop()
        sub.undeclare()
        session.close()
        hub.close()
    if len(window) < 2:
        raise RuntimeError("no joint states received")
    return period_figures(window)


def period_figures(periods: Any) -> dict[str, float]:
    """Rate (Hz) and period statistics (ms) of inter-arrival periods (s)."""
    import numpy as np

    dt = np.asarray(periods, dtype=float)
    return {
        "rate_hz": float(1.0 / np.mean(dt)),
        "period_median_ms": float(1e3 * np.median(dt)),
        "jitter_std_ms": float(1e3 * np.std(dt)),
        "period_p99_ms": float(1e3 * np.percentile(dt, 99)),
        "period_max_ms": float(1e3 * dt.max()),
    }


#: a separate process timing heartbeats (a subscriber in the planner's process would wait
#: for the same GIL as the heartbeat it measures); prints the times when its stdin closes
LISTENER = """
import json, os, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
session = zenoh.open(conf)
times = []
sub = session.declare_subscriber(sys.argv[2], lambda s: times.append(time.monotonic()))
print("ready", flush=True)
sys.stdin.read()
print(json.dumps(times), flush=True)
os._exit(0)
"""


def heartbeat_workloads(scenario: Path) -> dict[str, tuple[Any, str]]:
    """Requests to plan while the heartbeat is timed: the curve path (about 150 samples at
    1 mm), the curve there and back three times (about 900), and the scenario's targets."""
    import numpy as np

    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario

    curve_targets = load_scenario(shipped_scenario("curve_path.yaml")).model.targets
    assert curve_targets is not None and curve_targets.path is not None
    curve = np.asarray(curve_targets.path.points)
    back = np.concatenate([curve, curve[::-1][1:]])
    loaded = load_scenario(scenario)
    grid = targets_from_scenario(loaded, system_from_scenario(loaded)).points
    return {
        "path_150": (curve, "path"),
        "path_900": (np.concatenate([back, back[1:], back[1:]]), "path"),
        f"targets_{len(grid)}": (grid, "points"),
    }


def measure_heartbeat(scenario: Path, in_process: bool) -> dict[str, dict[str, float]]:
    """Heartbeat gaps (ms: p50, p99, max) seen by a separate process while the node plans
    each workload of :func:`heartbeat_workloads`; ``in_process``: the heartbeat thread of
    the planner process instead of the heartbeat process."""
    import subprocess
    import sys

    import numpy as np

    from planner.bus.session import Keys, open_session
    from planner.service.client import PlanClient, make_request
    from planner.service.node import BusAddress, PlannerNode, handler_from_scenario

    handler = handler_from_scenario(scenario)
    endpoint = _free_endpoint()
    hub = open_session(listen=True, endpoint=endpoint)
    bus = None if in_process else BusAddress(endpoint)
    node = PlannerNode(handler, hub, Keys("bench"), bus=bus).start()
    listener = subprocess.Popen([sys.executable, "-c", LISTENER, endpoint, "bench/heartbeat"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE)  # fmt: skip
    spans = {}
    try:
        assert listener.stdout is not None
        listener.stdout.readline()
        with PlanClient(endpoint=endpoint, prefix="bench") as client:
            client.wait_for_node("planner", 10.0)
            for name, (points, mode) in heartbeat_workloads(scenario).items():
                t0 = time.monotonic()
                client.request(make_request(points, path=mode == "path"), timeout=600.0)
                spans[name] = (t0, time.monotonic())
        out, _ = listener.communicate(b"", timeout=60)
    finally:
        if listener.poll() is None:
            listener.kill()
        node.close()
        hub.close()
    times = np.asarray(json.loads(out.decode().splitlines()[-1]))
    figures = {}
    for name, (t0, t1) in spans.items():
        inside = times[(times >= t0) & (times <= t1)]
        gaps = 1e3 * np.diff(np.concatenate([[t0], inside, [t1]]))
        figures[name] = {
            "plan_s": t1 - t0,
            "gap_p50_ms": float(np.median(gaps)),
            "gap_p99_ms": float(np.percentile(gaps, 99)),
            "gap_max_ms": float(gaps.max()),
        }
    return figures


# long: a typer command: 6 options (18 lines); it prints the service's figures
def command(
    scenario: Annotated[Path, typer.Option(help="Scenario whose system and targets are used.")] = (
        DEFAULT_SCENARIO
    ),
    n_single: Annotated[int, typer.Option("--n-single", help="Single-target requests.")] = 200,
    n_batch: Annotated[int, typer.Option("--n-batch", help="100-target requests.")] = 10,
    seconds: Annotated[float, typer.Option(help="Joint-state listening time (s).")] = 3.0,
    heartbeat: Annotated[
        bool,
        typer.Option(
            help="Time the heartbeat while the node plans a path and the scenario's "
            "targets, from its process and, for comparison, from a thread."
        ),
    ] = True,
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON on the last line.")] = (
        False
    ),
) -> None:
    """Request -> reply latency (1 and 100 targets) and joint_states rate and jitter."""
    from rich.console import Console

    from planner.errors import InputError

    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}")
    if n_single < 1 or n_batch < 1 or seconds <= 0:
        raise InputError("--n-single and --n-batch must be >= 1, --seconds > 0")
    console = Console(stderr=as_json)
    with console.status("timing requests on a private bus..."):
        lat = measure_latency(scenario, n_single, n_batch)
    with console.status(f"listening to joint_states for {seconds:g} s..."):
        js = measure_joint_states(seconds)
    beats = {}
    if heartbeat:
        for where, in_process in (("process", False), ("thread", True)):
            with console.status(f"timing the heartbeat ({where}) while planning..."):
                beats[where] = measure_heartbeat(scenario, in_process)
    s, b = lat["single"], lat["batch100"]
    goal = "meets" if s["median_ms"] <= GOAL_SINGLE_MS else "MISSES"
    console.print(
        f"1 target : median {s['median_ms']:.2f} ms, p95 {s['p95_ms']:.2f} ms, max "
        f"{s['max_ms']:.2f} ms over {s['n']} requests ({s['solved']} solved); {goal} the "
        f"{GOAL_SINGLE_MS:g} ms goal"
    )
    console.print(
        f"100 targets: median {b['median_ms']:.1f} ms, p95 {b['p95_ms']:.1f} ms over {b['n']}"
    )
    console.print(
        f"joint_states: {js['rate_hz']:.1f} Hz, period median {js['period_median_ms']:.2f} ms, "
        f"jitter std {js['jitter_std_ms']:.3f} ms, p99 {js['period_p99_ms']:.2f} ms, max "
        f"{js['period_max_ms']:.2f} ms"
    )
    for where, figures in beats.items():
        for name, f in figures.items():
            console.print(
                f"heartbeat ({where}) while planning {name} ({f['plan_s']:.1f} s): gap p50 "
                f"{f['gap_p50_ms']:.1f} ms, p99 {f['gap_p99_ms']:.1f} ms, max "
                f"{f['gap_max_ms']:.1f} ms"
            )
    if as_json:
        print(json.dumps({"latency": lat, "joint_states": js, "heartbeat": beats,
                          "goal_single_ms": GOAL_SINGLE_MS}))  # fmt: skip
