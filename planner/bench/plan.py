"""``beamrelay bench plan``: batch planning of target grids of 10^3, 10^4, 10^5 points.

The grid of ``scenarios/paper_n1.yaml`` (a 100 mm cube seen by one UR5e) is refined to each
size; each size runs in a fresh child process so that its peak memory (``ru_maxrss``) is its
own. Stages, timed separately, with the process's peak resident memory after each: beam IK
of every target (scene occlusion off), the checker's verdict on every solution (what
``beamrelay plan`` does before timing), visit order (``order: optimal``), timing (Ruckig
moves sampled at ``rate``), the plan document and its JSON text (``write s``: writing
plan.json alone), and ``beamrelay check`` of that text (read back with
:func:`~planner.io.plan_file.read_plan`). ``peak MB``: the largest peak resident memory of
the stages. Figures are printed, not asserted.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated, Any

import typer

DEFAULT_SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "paper_n1.yaml"
GRIDS = {1000: (10, 10, 10), 10_000: (25, 20, 20), 100_000: (50, 50, 40)}
STAGES = ("ik", "order", "timing", "document", "check")


def grid_shape(n: int) -> tuple[int, int, int]:
    """Points per axis of a grid of about ``n`` targets (exactly for the sizes in GRIDS)."""
    if n in GRIDS:
        return GRIDS[n]
    side = max(1, round(n ** (1 / 3)))
    return side, side, max(1, round(n / side**2))


def _maxrss_mb() -> float:
    import resource
    import sys

    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1e6 if sys.platform == "darwin" else rss / 1e3  # bytes on macOS, KiB on Linux


# long: one benchmark run: each stage timed in order with its peak memory, and the early exits between stages
def run_size(scenario: str, n: int, stages: tuple[str, ...]) -> dict[str, Any]:
    """Plan one grid of about ``n`` targets; figures per stage (s, MB)."""
    import numpy as np

    from planner.io.plan_file import write_plan
    from planner.io.resolved import resolved_scenario_dict
    from planner.io.scenario import (
        load_scenario,
        system_from_scenario,
        targets_from_scenario,
    )
    from planner.path.timing import points_trajectory
    from planner.path.tour import visit_order
    from planner.plan.document import plan_document, verify_solutions
    from planner.plan.scenario_planner import ik_options, plan_points

    loaded = load_scenario(scenario)
    model = loaded.model
    if model.targets.grid is None:
        raise ValueError("the benchmark scenario needs a grid target")
    model.targets.grid.n = list(grid_shape(n))
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    rate = float(model.trajectory.rate)
    row: dict[str, Any] = {"targets": len(targets), "grid": model.targets.grid.n,
                           "start_rss_mb": _maxrss_mb()}  # fmt: skip

    def stage(name: str, t0: float) -> None:
        row[f"{name}_s"] = time.perf_counter() - t0
        row[f"{name}_peak_rss_mb"] = _maxrss_mb()

    t0 = time.perf_counter()
    sols = plan_points(system, targets, ik_options(model.solver))
    stage("ik", t0)
    t0 = time.perf_counter()
    resolved = resolved_scenario_dict(loaded)
    sols = verify_solutions(system, resolved, targets, sols)
    stage("verify", t0)
    Q = np.array([s.q for s in sols if s.ok])
    row["solved"] = len(Q)
    if "order" not in stages or not len(Q):
        return row
    t0 = time.perf_counter()
    order = visit_order(Q, system.home, system.limits)
    stage("order", t0)
    if "timing" not in stages:
        return row
    t0 = time.perf_counter()
    traj, _ = points_trajectory(system, Q[order], system.home, 0.0, rate, "given")
    stage("timing", t0)
    row |= {"duration_s": traj.duration, "duration_given_order_s": None, "samples": len(traj.t),
            "trajectory_mb": sum(a.nbytes for a in (traj.t, traj.q, traj.qd, traj.qdd)) / 1e6}  # fmt: skip
    P = np.vstack([system.home, Q])
    from planner.path.rest_to_rest import move_time

    row["duration_given_order_s"] = float(move_time(P[:-1], P[1:], system.limits).sum())
    if "document" not in stages:
        return row
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "plan.json"
        t0 = time.perf_counter()
        doc = plan_document(system, targets, sols, resolved,
                            traj.to_plan_arrays(system), trajectory_requested=True, verify=False)  # fmt: skip
        del traj
        t1 = time.perf_counter()
        with path.open("w") as fh:
            write_plan(doc, fh)
        row["write_s"] = time.perf_counter() - t1  # plan.json's text alone (goal: <= 10 s at 10^5)
        del doc
        stage("document", t0)
        row["plan_json_mb"] = path.stat().st_size / 1e6
        if "check" in stages:
            from planner.io.plan_file import read_plan
            from planner.verify.check import check_plan

            t0 = time.perf_counter()
            results = check_plan(read_plan(path))
            stage("check", t0)
            row["check_violations"] = sum(len(r.findings) for r in results)
    return row


def _child(scenario: str, n: int, stages: tuple[str, ...], conn: Any) -> None:
    try:
        conn.send(run_size(scenario, n, stages))
    except BaseException as exc:  # report, never hang the parent
        conn.send({"targets": n, "error": f"{type(exc).__name__}: {exc}"})
    finally:
        conn.close()


def _in_child(scenario: Path, n: int, stages: tuple[str, ...]) -> dict[str, Any]:
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(str(scenario), n, stages, send))
    proc.start()
    send.close()
    try:
        row: dict[str, Any] = recv.recv()
    except EOFError:
        row = {"targets": n, "error": f"child process died (exit status {proc.exitcode})"}
    proc.join()
    if proc.exitcode not in (0, None) and "error" not in row:
        row["error"] = f"child process exit status {proc.exitcode}"
    return row


def command(
    scenario: Annotated[Path, typer.Option(help="Grid scenario to refine.")] = DEFAULT_SCENARIO,
    sizes: Annotated[
        str, typer.Option(help="Comma-separated target counts.")
    ] = "1000,10000,100000",
    stages: Annotated[
        str, typer.Option(help=f"Comma-separated stages to run, in order: {','.join(STAGES)}.")
    ] = ",".join(STAGES),
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON (last line).")] = False,
) -> None:
    """Batch-planning time and peak memory per stage for grids of several sizes."""
    from rich.console import Console
    from rich.table import Table

    from planner.errors import InputError

    try:
        ns = [int(k) for k in sizes.split(",")]
    except ValueError as exc:
        raise InputError(f"must be comma-separated integers: {sizes!r}", "--sizes") from exc
    if any(n < 1 for n in ns):
        raise InputError(f"target counts must be >= 1: {sizes!r}", "--sizes")
    chosen = tuple(s.strip() for s in stages.split(","))
    unknown = [s for s in chosen if s not in STAGES]
    if unknown:
        raise InputError(f"unknown stage {unknown[0]!r} (choose from {', '.join(STAGES)})",
                         "--stages")  # fmt: skip
    if not scenario.is_file():
        raise InputError(f"no such file: {scenario}", "--scenario")
    err = Console(stderr=True)
    rows = []
    for n in ns:
        err.print(f"planning a grid of {n} targets ...")
        rows.append(_in_child(scenario, n, chosen))
    table = Table(title=f"batch planning ({scenario.name})")
    cols = [("targets", "N", "{}"), ("ik_s", "IK s", "{:.1f}"), ("verify_s", "verify s", "{:.1f}"),
            ("order_s", "order s", "{:.1f}"),
            ("timing_s", "timing s", "{:.1f}"), ("document_s", "doc s", "{:.1f}"),
            ("write_s", "write s", "{:.1f}"),
            ("check_s", "check s", "{:.1f}"), ("duration_s", "tour s", "{:.0f}"),
            ("duration_given_order_s", "given s", "{:.0f}"), ("plan_json_mb", "json MB",
            "{:.0f}"), ("check_peak_rss_mb", "peak MB", "{:.0f}")]  # fmt: skip
    for _, title, _ in cols:
        table.add_column(title, justify="right")
    for r in rows:
        peak = max((v for k, v in r.items() if k.endswith("peak_rss_mb")), default=None)
        shown = {**r, "check_peak_rss_mb": peak}
        table.add_row(*[fmt.format(shown[k]) if shown.get(k) is not None else "-"
                        for k, _, fmt in cols])  # fmt: skip
    Console().print(table)
    for r in rows:
        if "error" in r:
            err.print(f"[red]{r['targets']} targets: {r['error']}")
    if as_json:
        print(json.dumps({"bench": "plan", "scenario": str(scenario), "rows": rows}))
