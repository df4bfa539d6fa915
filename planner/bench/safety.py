"""``beamrelay bench safety``: distance queries per second and the cost of a full check.

For N = 1, 2, 3 UR5e robots (bases 1.05 m apart, facing the middle), at random joint
configurations (rad): every collision pair's distance in one Pinocchio call (queries/s and
µs per configuration), the beam checks (an N + 1 segment polyline against every arm part and
a keep-out sphere), the full per-sample check (pairs + beam), the swept check of a 1 s move
at 500 Hz, and the independent numpy re-check of the arm pairs. Figures are printed, not
asserted. ``python -m planner.bench.safety [--json]``.
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
    from planner.safety import (
        SafetyWorld,
        all_pair_distances,
        beam_arm,
        beam_keep_out,
        beam_points,
        check_sweep,
        sphere,
    )
    from planner.verify import arms

    system = bench_system(n)
    world = SafetyWorld(system, keep_out=[sphere("eye", 0.016, make_T(p=[0.2, 0.3, 0.1]))])
    rng = np.random.default_rng(seed)
    Q = system.home + rng.uniform(-0.5, 0.5, (256, system.nq))
    n_pairs = len(world.pair_kinds)
    end = np.array([0.0, 0.4, 0.0])

    def beam(i: int) -> None:
        pts = beam_points(world, Q[i % 256], end)
        beam_arm(world, Q[i % 256], pts)
        beam_keep_out(world, pts)

    def full(i: int) -> None:
        all_pair_distances(world, Q[i % 256])
        beam(i)

    def numpy_pairs(i: int) -> None:
        shapes = [
            arms.arm_shapes(r.world_T_base, q, r.mirror.flange_T_mirror, r.mirror.size)
            for r, q in zip(system.robots, system.split_q(Q[i % 256]).values(), strict=True)
        ]
        for k, a in enumerate(shapes):
            arms.arm_self_distances(a)
            for b in shapes[k + 1 :]:
                arms.arm_arm_distances(a, b)

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
        "numpy_pairs_ms": _rate(numpy_pairs, 2, seconds) * 1e3,
    }


def command(
    robots: Annotated[str, typer.Option(help="Comma-separated robot counts N.")] = "1,2,3",
    seconds: Annotated[float, typer.Option(help="Minimum time per figure, s.")] = 0.5,
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON (last line).")] = False,
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
        "numpy ms",
    ):
        table.add_column(col)
    for r in rows:
        table.add_row(
            str(r["n_robots"]), str(r["pairs"]), f"{r['distance_queries_per_s']:.3g}",
            f"{r['all_pairs_us']:.1f}", f"{r['beam_check_us']:.1f}", f"{r['full_check_us']:.1f}",
            f"{r['sweep_us_per_sample']:.1f}", f"{r['numpy_pairs_ms']:.2f}",
        )  # fmt: skip
    Console().print(table)
    if as_json:
        print(json.dumps({"bench": "safety", "rows": rows}))


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
