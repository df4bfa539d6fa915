"""``beamrelay bench safety``: distance queries per second, the cost of safety in the IK and
the dense trajectory check against the planning time.

For N = 1, 2, 3 UR5e robots (bases 1.05 m apart, facing the middle), at random joint
configurations (rad): every collision pair's distance in one Pinocchio call (queries/s and
µs per configuration), the beam checks (an N + 1 segment polyline against every arm part and
a keep-out sphere), the full per-sample check (pairs + beam), the swept check of a 1 s move
at 500 Hz, and the independent numpy re-check of the arm pairs (batched over the 256
configurations, per configuration). Then, on the paper's N = 1
grid (``scenarios/paper_n1.yaml``): the per-target IK median with the safety rules on and
off (blocks of targets alternated, so machine load hits both alike), and the whole plan
with its dense trajectory check (swept arms, beam while the laser is on) against the
planning time. Figures are printed, not asserted. ``python -m planner.bench.safety [--json]``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Annotated, Any

import numpy as np
import typer

from planner.model.system import System
from schemas import defaults

GAP = 1.05  # m between neighbouring bases


def bench_system(n: int) -> System:
    """N UR5e on a circle with neighbouring bases ``GAP`` apart, facing its centre."""
    from planner.model.build import build_system
    from planner.model.transforms import look_at, make_T, rot_z

    radius = 0.0 if n == 1 else GAP / (2 * np.sin(np.pi / n))
    angles = [2 * np.pi * i / n for i in range(n)]
    bases = [
        make_T(rot_z(a + np.pi), [radius * np.cos(a), radius * np.sin(a), 0.0]) for a in angles
    ]
    return build_system(look_at([0.3, -0.5, 0.3], [0.0, 0.0, 0.8]), bases)


def _rate(fn: Callable[[int], object], count: int, seconds: float) -> float:
    """Seconds per call of fn(i), over at least ``count`` calls or ``seconds``."""
    done, t0 = 0, time.perf_counter()
    while done < count or time.perf_counter() - t0 < seconds:
        fn(done)
        done += 1
    return (time.perf_counter() - t0) / done


def measure(n: int, seconds: float = 0.5, seed: int = 0) -> dict[str, Any]:
    """Figures for N = ``n`` robots."""
    from planner.model.transforms import make_T
    from planner.safety import all_pair_distances, beam_points, check_sweep, sphere
    from planner.safety.checks import DEFAULT_CLEARANCE
    from planner.safety.model import Safety
    from planner.verify.safety import Setup, arm_hits

    system = bench_system(n)
    rng = np.random.default_rng(seed)
    Q = system.home + rng.uniform(-0.5, 0.5, (256, system.nq))
    rules = Safety(system, keep_out=[sphere("eye", 0.016, make_T(p=[0.2, 0.3, 0.1]))])
    world = rules.world
    n_pairs = len(world.pair_kinds)
    end = np.array([0.0, 0.4, 0.0])

    def beam(i: int) -> None:
        rules.beam(Q[i % 256], beam_points(world, Q[i % 256], end))

    def full(i: int) -> None:
        all_pair_distances(world, Q[i % 256])
        beam(i)

    setup = Setup(
        [Setup.robot(r.name, r.world_T_base, r.mirror.flange_T_mirror, r.mirror.size)
         for r in system.robots],
        system.world_T_laser, None, [], [], DEFAULT_CLEARANCE, np.radians(10.0), 0.01, [],
    )  # fmt: skip
    batch = {r.name: q for r, q in zip(system.robots, np.hsplit(Q, n), strict=True)}

    def numpy_pairs(i: int) -> None:
        arm_hits(setup, batch)

    pairs_s = _rate(lambda i: all_pair_distances(world, Q[i % 256]), 50, seconds)
    t = np.arange(0.0, 1.0 + 1e-12, 1 / defaults.SERVO_RATE_HZ)
    move = system.home + np.outer(t, rng.uniform(-0.3, 0.3, system.nq))
    sweep_s = _rate(lambda i: check_sweep(world, t, move), 1, seconds)
    return {
        "n_robots": n,
        "pairs": n_pairs,
        "parts": len(world.parts),
        "distance_queries_per_s": n_pairs / pairs_s,
        "all_pairs_us": pairs_s * 1e6,
        "beam_check_us": _rate(beam, 20, seconds) * 1e6,
        "full_check_us": _rate(full, 20, seconds) * 1e6,
        "sweep_us_per_sample": sweep_s / len(t) * 1e6,
        "numpy_pairs_us": _rate(numpy_pairs, 2, seconds) / len(Q) * 1e6,
    }


def ik_figures(scenario: str, count: int, block: int = 50) -> dict[str, Any]:
    """Per-target IK time (s) with the safety rules on and off on the first ``count``
    targets of ``scenario``, blocks of ``block`` targets alternating between the two."""
    from planner.ik import BeamIK
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.plan.scenario_planner import ik_options
    from planner.safety.model import Safety

    scn = load_scenario(scenario)
    system = system_from_scenario(scn)
    targets = targets_from_scenario(scn, system)
    options = ik_options(scn.model.solver)
    solvers = {"off": BeamIK(system, options), "on": BeamIK(system, options,
                                                           Safety.from_scenario(scn, system))}  # fmt: skip
    times: dict[str, list[float]] = {"off": [], "on": []}
    q = {"off": system.home, "on": system.home}
    for a in range(0, min(count, len(targets)), block):
        for key, ik in solvers.items():
            for k in range(a, min(a + block, count, len(targets))):
                t0 = time.perf_counter()
                sol = ik.solve(targets.points[k], targets.normal(k), q[key])
                times[key].append(time.perf_counter() - t0)
                q[key] = sol.q if sol.q is not None else q[key]
    off, on = float(np.median(times["off"])), float(np.median(times["on"]))
    return {"targets": len(times["on"]), "ik_median_off_us": off * 1e6,
            "ik_median_on_us": on * 1e6, "ik_ratio": on / off}  # fmt: skip


def plan_figures(scenario: str) -> dict[str, Any]:
    """The whole plan of ``scenario`` with the safety rules: planning time (s), the dense
    trajectory check time (s) and samples, and their ratio."""
    from planner.plan.pipeline import run_scenario

    t0 = time.perf_counter()
    out = run_scenario(scenario, progress=False)
    total = time.perf_counter() - t0
    extra = out.doc["metrics"]["extra"]
    check = float(extra.get("safety_check_time", float("nan")))
    samples = len(out.doc["trajectory"]["t"]) if out.doc["trajectory"] else 0
    return {"plan_s": total, "dense_check_s": check, "dense_check_ratio": check / total,
            "trajectory_samples": samples, "n_ok": out.doc["metrics"]["n_ok"]}  # fmt: skip


def command(
    robots: Annotated[str, typer.Option(help="Comma-separated robot counts N.")] = "1,2,3",
    seconds: Annotated[float, typer.Option(help="Minimum time per figure, s.")] = 0.5,
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON (last line).")] = False,
    ik_targets: Annotated[int, typer.Option(help="Targets of the IK comparison (0: skip).")] = 300,
    plan: Annotated[bool, typer.Option(help="Plan the paper grid with its dense check.")] = True,
) -> None:
    """Collision distance queries per second and per-sample check cost for N robots."""
    from rich.console import Console
    from rich.table import Table

    from planner.errors import InputError

    try:
        Ns = [int(k) for k in robots.split(",")]
    except ValueError as exc:
        raise InputError(f"--robots must be integers: {robots!r}") from exc
    if any(n < 1 or n > 8 for n in Ns):
        raise InputError(f"--robots must be between 1 and 8, got {robots!r}")
    if ik_targets < 0:
        raise InputError(f"--ik-targets must be >= 0, got {ik_targets}")
    rows = [measure(n, seconds) for n in Ns]
    table = Table(title="safety geometry (coal via Pinocchio; numpy re-check)")
    for col in (
        "N",
        "pairs",
        "queries/s",
        "all pairs µs",
        "beam µs",
        "full µs",
        "sweep µs/sample",
        "numpy µs/config",
    ):
        table.add_column(col)
    for r in rows:
        table.add_row(
            str(r["n_robots"]), str(r["pairs"]), f"{r['distance_queries_per_s']:.3g}",
            f"{r['all_pairs_us']:.1f}", f"{r['beam_check_us']:.1f}", f"{r['full_check_us']:.1f}",
            f"{r['sweep_us_per_sample']:.1f}", f"{r['numpy_pairs_us']:.1f}",
        )  # fmt: skip
    console = Console()
    console.print(table)
    out: dict[str, Any] = {"bench": "safety", "rows": rows}
    from planner.data import shipped_scenario

    paper = str(shipped_scenario("paper_n1.yaml"))
    if ik_targets:
        ik = out["ik"] = ik_figures(paper, ik_targets)
        console.print(f"IK per target (paper grid, N = 1, {ik['targets']} targets): median "
                      f"{ik['ik_median_off_us']:.0f} µs without the safety rules, "
                      f"{ik['ik_median_on_us']:.0f} µs with them ({ik['ik_ratio']:.2f}x)")  # fmt: skip
    if plan:
        p = out["plan"] = plan_figures(paper)
        console.print(f"paper grid plan: {p['plan_s']:.2f} s; dense trajectory check "
                      f"({p['trajectory_samples']} samples) {p['dense_check_s']:.3f} s = "
                      f"{100 * p['dense_check_ratio']:.1f} % of it")  # fmt: skip
    if as_json:
        print(json.dumps(out))


def main() -> None:
    """``python -m planner.bench.safety``: a user mistake is one line on stderr, exit 2."""
    import sys

    from planner.errors import InputError

    try:
        typer.run(command)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
