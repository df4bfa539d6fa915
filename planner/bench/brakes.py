"""``beamrelay bench brakes``: false brakes of a busy machine during continuous execution.

Starts the simulated system as ``beamrelay up`` does (planner, camera, robot drivers, the
hub; a private loopback port and prefix), optionally ``--load N`` CPU-burning processes
(normal priority, each ends by itself after the run), and executes the scenario's targets,
``--batch`` per request, one request after the other for ``--minutes`` minutes. Counted:

- false brakes: executions a driver stopped with "planner heartbeat lost" (nothing failed:
  the planner is alive, the heartbeat was late), from the execution's fault or, when the
  planner's own stop of every robot came first and the fault names it, from the planner's
  log (it names the braking arm's reason);
- other faults and rejected executions;
- heartbeat gaps over 50 and 100 ms as received by the bench's own session (a client of the
  hub, its Zenoh threads raised like a driver's), with the largest gap;
- the machine's 1-minute load average (sampled every 10 s).

``--no-rt`` runs the system with ``BEAMRELAY_NO_RT=1`` (nice only, no SCHED_FIFO) to
measure what real-time priority buys. Goal: 0 false brakes per 10 minutes at load >= 8.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.bench.service import DEFAULT_SCENARIO, _free_endpoint
from planner.bus.priority import NO_RT_ENV
from schemas.brakes import Brake

PREFIX = "benchbrakes"
BRAKE = Brake.HEARTBEAT_LOST.value
MAX_LOAD = 32  # burners at most
BURN = "import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end:\n    pass\n"


@contextmanager
def cpu_load(n: int, seconds: float) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``n`` processes that each burn one CPU for ``seconds`` s and then exit (killed on the
    way out if still running)."""
    procs = [subprocess.Popen([sys.executable, "-c", BURN.format(seconds=seconds)],
                              stdin=subprocess.DEVNULL) for _ in range(n)]  # fmt: skip
    try:
        yield procs
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()


@contextmanager
def simulated_system(scenario: Path, endpoint: str, log_dir: Path, rt: bool) -> Iterator[Any]:
    """``beamrelay up`` on ``endpoint`` under :data:`PREFIX` (its own process group);
    stopped with SIGTERM on the way out, SIGKILLed if it does not stop in 20 s."""
    env = dict(os.environ)
    if not rt:
        env[NO_RT_ENV] = "1"
    argv = [sys.executable, "-m", "planner.cli", "up", str(scenario), "--endpoint", endpoint,
            "--prefix", PREFIX, "--no-live", "--log-dir", str(log_dir)]  # fmt: skip
    out = (log_dir / "up.log").open("wb")
    up = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=env,
                          start_new_session=True)  # fmt: skip
    try:
        yield up
    finally:
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, signal.SIGKILL)
            up.wait()
        out.close()


def gap_figures(arrivals: list[float], t0: float, t1: float) -> dict[str, Any]:
    """Heartbeat gaps (ms) between arrivals (monotonic s) inside [t0, t1]."""
    import numpy as np

    t = np.asarray([a for a in arrivals if t0 <= a <= t1])
    gaps = 1e3 * np.diff(t) if len(t) > 1 else np.zeros(1)
    return {
        "beats": len(t),
        "gaps_over_50ms": int((gaps > 50).sum()),
        "gaps_over_100ms": int((gaps > 100).sum()),
        "gap_p99_ms": float(np.percentile(gaps, 99)),
        "gap_max_ms": float(gaps.max()),
    }


def warm_up(client: Any, points: Any, timeout: float = 60.0) -> None:
    """One plan (not executed) once the planner's queryable answers through the hub."""
    from planner.service.client import RequestError, make_request

    deadline = time.monotonic() + timeout
    while True:
        try:
            client.request(make_request(points), timeout=30.0)
            return
        except RequestError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def execute_for(
    scenario: Path, endpoint: str, seconds: float, batch: int, dwell: float
) -> dict[str, Any]:
    """Execute the scenario's targets, ``batch`` per request, each held ``dwell`` s (the
    arm executes, and watches the heartbeat, for most of the run), for ``seconds`` s."""
    from planner.bus.priority import raised_priority
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.service.client import PlanClient, make_request

    scn = load_scenario(scenario)
    points = targets_from_scenario(scn, system_from_scenario(scn)).points
    beats: list[float] = []  # monotonic s of arrival
    sent: list[float] = []  # the beats' own UNIX time stamps (the sender's clock)
    counts = {"executions": 0, "false_brakes": 0, "other_faults": 0, "rejected": 0}
    faults: list[str] = []
    loads: list[float] = []
    with raised_priority():  # the bench listens like a driver: its Zenoh threads first
        client = PlanClient(endpoint=endpoint, prefix=PREFIX, connect_timeout=30.0)
    with client:
        for node in ("planner", *(r.name for r in scn.model.system.robots)):
            if not client.wait_for_node(node, 120.0):
                raise RuntimeError(f"{node} did not come up within 120 s")
        warm_up(client, points[:1])

        def on_beat(sample: Any) -> None:
            beats.append(time.monotonic())
            sent.append(float(json.loads(sample.payload.to_bytes())["t"]))

        sub = client.session.declare_subscriber(client.keys.heartbeat, on_beat)
        t0 = time.monotonic()
        t_end, next_load, k, moving = t0 + seconds, t0, 0, 0.0
        while time.monotonic() < t_end:
            if time.monotonic() >= next_load:
                loads.append(os.getloadavg()[0])
                next_load += 10.0
            sel = points[[(k + i) % len(points) for i in range(batch)]]
            k += batch
            req = make_request(sel, execute=True, dwell=dwell)
            plan, _ = client.execute(req, timeout=30.0 + batch * dwell, settle=0.0)
            if plan.get("execution") != "accepted":
                counts["rejected"] += 1
                faults.append(f"rejected: {plan.get('execution_reason')}")
                continue
            counts["executions"] += 1
            moving += float((plan.get("trajectory") or {}).get("t", [0.0])[-1])
            fault = client.recorder.fault_of(plan.get("id"))
            if fault is not None:
                counts["false_brakes" if BRAKE in fault else "other_faults"] += 1
                faults.append(fault)
        t1 = time.monotonic()
        sub.undeclare()
    return {**counts, "seconds": t1 - t0, "moving_s": moving, "faults": faults[:20],
            "load1_min": min(loads), "load1_mean": sum(loads) / len(loads),
            "heartbeat": gap_figures(beats, t0, t1),
            "heartbeat_sent": gap_figures(sent, sent[0] if sent else 0.0, float("inf"))}  # fmt: skip


def reclassify(fig: dict[str, Any], planner_log: Path) -> None:
    """Count as false brakes the executions the planner stopped because a driver braked for
    a late heartbeat (their fault then reads "stop requested"), from the planner's log."""
    text = planner_log.read_text(errors="replace") if planner_log.is_file() else ""
    logged = sum(BRAKE in ln and "stopping every robot" in ln for ln in text.splitlines())
    extra = min(max(0, logged - fig["false_brakes"]), fig["other_faults"])
    fig["false_brakes"] += extra
    fig["other_faults"] -= extra


# long: a typer command: 7 options (15 lines); it runs the loads and prints one line per load
def command(
    minutes: Annotated[float, typer.Option(help="Continuous execution time (min).")] = 10.0,
    load: Annotated[int, typer.Option(help="CPU-burning processes beside the system.")] = 0,
    rt: Annotated[
        bool, typer.Option("--rt/--no-rt", help="Real-time priority (SCHED_FIFO) if permitted.")
    ] = True,
    batch: Annotated[int, typer.Option(help="Targets per executed request.")] = 4,
    dwell: Annotated[float, typer.Option(help="Hold on each target (s): time executing.")] = 2.0,
    scenario: Annotated[Path, typer.Option(help="Scenario whose system and targets are used.")] = (
        DEFAULT_SCENARIO
    ),
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON on the last line.")] = (
        False
    ),
) -> None:
    """False brakes ("planner heartbeat lost") and heartbeat gaps while executing."""
    from rich.console import Console

    from planner.errors import InputError

    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}")
    if not 0 < minutes <= 120:
        raise InputError(f"--minutes must be in (0, 120], got {minutes:g}")
    if not 0 <= load <= MAX_LOAD:
        raise InputError(f"--load must be in [0, {MAX_LOAD}], got {load}")
    if batch < 1:
        raise InputError(f"--batch must be >= 1, got {batch}")
    if not 0 <= dwell <= 10:
        raise InputError(f"--dwell must be in [0, 10] s, got {dwell:g}")
    console = Console(stderr=as_json)
    log_dir = Path(tempfile.mkdtemp(prefix="beamrelay-bench-brakes-"))
    seconds = 60.0 * minutes
    with simulated_system(scenario, _free_endpoint(), log_dir, rt) as up:
        endpoint = up.args[up.args.index("--endpoint") + 1]
        with cpu_load(load, seconds + 180.0), console.status(f"executing for {minutes:g} min..."):
            fig = execute_for(scenario, endpoint, seconds, batch, dwell)
    banners = [f"{f.stem}: {ln.strip()}" for f in sorted(log_dir.glob("*.log"))
               for ln in f.read_text(errors="replace").splitlines() if "priority:" in ln]  # fmt: skip
    fig.update(minutes=minutes, load=load, rt=rt, log_dir=str(log_dir), priority=banners)
    reclassify(fig, log_dir / "planner.log")
    hb = fig["heartbeat"]
    per10 = fig["false_brakes"] * 600.0 / fig["seconds"]
    console.print(
        f"{fig['executions']} executions in {fig['seconds']:.0f} s ({fig['moving_s']:.0f} s "
        f"executing), load {fig['load1_min']:.1f}-{fig['load1_mean']:.1f} (min-mean), "
        f"{'SCHED_FIFO' if rt else 'no SCHED_FIFO'}, {load} burners"
    )
    console.print(
        f"false brakes: {fig['false_brakes']} ({per10:.1f} per 10 min; goal 0), other faults "
        f"{fig['other_faults']}, rejected {fig['rejected']}"
    )
    console.print(
        f"heartbeat gaps: {hb['gaps_over_50ms']} > 50 ms, {hb['gaps_over_100ms']} > 100 ms, "
        f"p99 {hb['gap_p99_ms']:.1f} ms, max {hb['gap_max_ms']:.1f} ms ({hb['beats']} beats)"
    )
    hs = fig["heartbeat_sent"]
    console.print(
        f"  of which at the sender (beat time stamps): {hs['gaps_over_50ms']} > 50 ms, "
        f"{hs['gaps_over_100ms']} > 100 ms, max {hs['gap_max_ms']:.1f} ms"
    )
    for line in banners:
        console.print(line)
    if as_json:
        print(json.dumps(fig))
