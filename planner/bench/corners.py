"""``beamrelay bench corners``: random polylines with turns around ``corner_deg``, planned.

Each polyline lies on the S-curve scenario's board (the shipped ``s_curve.yaml`` layout):
``vertices`` vertices with edges 4-9 mm long, turns drawn around ``corner_deg`` (|N(20, 8)|
deg: on both sides of it), an S (the first half turning one way, the rest the other) or
random signs, sample spacing 0.5 or 1 mm, spot speed 10-30 mm/s, with or without normals,
at a random heading. Each is planned as ``beamrelay plan`` does (the written plan read back
and checked by ``beamrelay check``'s checks), then measured from the plan's output alone
with numpy (:func:`measure`): the marked speed at the first and last step of every mark
(spots traced by the numpy DH model onto the board plane), the targets' distance from the
scenario's polyline, each vertex's distance from its nearest target and whether
``metrics.n_ok`` counts the solutions that are ``ok``. Prints the worst figures over all
polylines; figures are printed, not asserted. SI units; ratios are fractions of the spot
speed.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated, Any, NamedTuple

import numpy as np
import typer

from planner.model.transforms import Array

BOARD_Z = -0.06  # m: the S-curve board's top face (world z)
BOARD_CENTRE = (-0.4920, -0.5680)  # m: where the S-curve layout's home beam lands
TURN_DEG = (20.0, 8.0)  # deg: mean and spread of the turn angles
EDGE_M = (0.004, 0.009)  # m: edge lengths
SPEED_MPS = (0.01, 0.03)  # m/s: spot speeds
SPACINGS_M = (0.0005, 0.001)


class Polyline(NamedTuple):
    """A random path: vertices (n x 3, world, on the board), whether normals are given,
    sample spacing (m) and spot speed (m/s)."""

    vertices: Array
    normals: bool
    spacing: float
    speed: float


def random_polyline(rng: np.random.Generator, vertices: int = 15,
                    corner_deg: float = TURN_DEG[0]) -> Polyline:  # fmt: skip
    """One polyline on the board with turns ~ |N(corner_deg, 8 deg)| (see the module)."""
    turns = np.abs(rng.normal(corner_deg, TURN_DEG[1], vertices - 2))
    if rng.random() < 0.5:  # an S: the first half turns left, the rest right
        turns[(vertices - 2) // 2 :] *= -1
    else:
        turns *= rng.choice([-1.0, 1.0], vertices - 2)
    heading = rng.uniform(0, 2 * np.pi) + np.concatenate([[0.0], np.cumsum(np.radians(turns))])
    edges = rng.uniform(*EDGE_M, vertices - 1)[:, None] * np.column_stack(
        [np.cos(heading), np.sin(heading)]
    )
    xy = np.vstack([[0.0, 0.0], np.cumsum(edges, axis=0)])
    xy += np.asarray(BOARD_CENTRE) - 0.5 * (xy.min(axis=0) + xy.max(axis=0))
    V = np.column_stack([xy, np.full(vertices, BOARD_Z)])
    return Polyline(V, bool(rng.random() < 0.7), float(rng.choice(SPACINGS_M)),
                    float(rng.uniform(*SPEED_MPS)))  # fmt: skip


def scenario(line: Polyline, base: dict[str, Any], corner_deg: float = 20.0) -> dict[str, Any]:
    """The scenario mapping: ``base`` (the S-curve scenario) with this polyline's path."""
    out = json.loads(json.dumps(base))
    path = {"closed": False, "spacing": line.spacing, "corner_deg": corner_deg, "smooth": False,
            "points": line.vertices.tolist()}  # fmt: skip
    if line.normals:
        path["normals"] = [[0.0, 0.0, 1.0]] * len(line.vertices)
    out["targets"] = {"frame": "world", "path": path}
    out["trajectory"] = {**out.get("trajectory", {}), "spot_speed": line.speed}
    return out


def _to_polyline(X: Array, V: Array) -> Array:
    """Distance (m) of each point (M x 3) from the polyline ``V`` (n x 3)."""
    a, ab = V[:-1], np.diff(V, axis=0)
    u = np.clip(np.einsum("mkj,kj->mk", X[:, None] - a, ab) / (ab * ab).sum(1), 0, 1)
    return np.asarray(np.linalg.norm(X[:, None] - (a + u[..., None] * ab), axis=2).min(axis=1))


def board_spots(plan: dict[str, Any], idx: Array) -> Array:
    """The spot on the board plane (world, m) at trajectory samples ``idx``."""
    from planner.verify.trajectory import trace_last_ray

    traj = plan["trajectory"]
    q = {r: np.asarray(traj["q"][r], dtype=float)[idx] for r in traj["q"]}
    p, v = trace_last_ray(plan["scenario"], q)
    return np.asarray(p + ((BOARD_Z - p[:, 2]) / v[:, 2])[:, None] * v)


def mark_end_ratios(plan: dict[str, Any]) -> tuple[Array, Array]:
    """Per mark (``laser_on`` interval): the spot speed over its first and last step as
    fractions of the spot speed (columns start, end), and whether each step lies in a
    reported slowdown (same shape)."""
    traj = plan["trajectory"]
    t = np.asarray(traj["t"], dtype=float)
    rate = 1.0 / float(t[1] - t[0])
    v0 = float(plan["scenario"]["trajectory"]["spot_speed"])
    rows, slow = [], []
    for t0, t1 in traj["laser_on"]:
        i0, i1 = int(np.ceil(t0 * rate - 1e-6)), int(np.floor(t1 * rate + 1e-6))
        s = board_spots(plan, np.array([i0, i0 + 1, i1 - 1, i1]))
        rows.append([np.linalg.norm(s[1] - s[0]) * rate / v0,
                     np.linalg.norm(s[3] - s[2]) * rate / v0])  # fmt: skip
        steps = (t[i0], t[i1 - 1])
        slow.append([any(float(d["t0"]) - 1.5 / rate <= x <= float(d["t1"]) + 1.5 / rate
                         for d in traj.get("slowdowns") or []) for x in steps])  # fmt: skip
    return np.array(rows).reshape(-1, 2), np.array(slow, dtype=bool).reshape(-1, 2)


class Measured(NamedTuple):
    """Figures of one plan from its output alone (m; ratios of the spot speed)."""

    start_end: Array  # marks x 2: speed ratio over the first / last step
    in_slowdown: Array  # marks x 2: that step lies in a reported slowdown
    target_distance_max: float  # targets from the scenario's polyline
    vertex_gap_max: float  # vertices from their nearest target
    n_ok_agrees: bool  # metrics.n_ok == solutions with status ok == n_targets


def measure(plan: dict[str, Any]) -> Measured:
    """:class:`Measured` of a path plan (numpy only: the plan's scenario, targets,
    solutions, metrics and trajectory)."""
    V = np.asarray(plan["scenario"]["targets"]["path"]["points"], dtype=float)
    P = np.array([tg["p"] for tg in plan["targets"]], dtype=float)
    gap = max(float(np.linalg.norm(P - v, axis=1).min()) for v in V)
    ok = sum(s["status"] == "ok" for s in plan["solutions"])
    m = plan["metrics"]
    ratios, slow = mark_end_ratios(plan)
    return Measured(ratios, slow, float(_to_polyline(P, V).max()), gap,
                    m["n_ok"] == ok == m["n_targets"] == len(plan["targets"]))  # fmt: skip


def plan_polyline(line: Polyline, base: dict[str, Any], workdir: Path, name: str
                  ) -> tuple[dict[str, Any], int]:  # fmt: skip
    """Plan one polyline as ``beamrelay plan`` does: the plan read back from its JSON and
    the number of check findings on it."""
    import io

    import yaml

    from planner.io.plan_file import write_plan
    from planner.plan.pipeline import run_scenario
    from planner.verify.check import check_plan

    path = workdir / f"{name}.yaml"
    path.write_text(yaml.safe_dump(scenario(line, base), default_flow_style=None))
    out = run_scenario(path, progress=False)
    buf = io.StringIO()
    write_plan(out.doc, buf)
    plan = json.loads(buf.getvalue())
    return plan, sum(len(r.findings) for r in check_plan(plan, workdir))


def run_one(k: int, seed: int, workdir: Path) -> dict[str, Any]:
    """Plan and measure polyline ``k`` of the sweep with seed ``seed`` (its own generator,
    so sweeps split over processes give the same polylines)."""
    import yaml

    from planner.data import shipped_scenario
    from planner.errors import PlanError

    base = yaml.safe_load(shipped_scenario("s_curve.yaml").read_text())
    line = random_polyline(np.random.default_rng([seed, k]))
    try:
        plan, findings = plan_polyline(line, base, workdir, f"corners{k}")
    except PlanError as exc:  # nothing to measure: counted as failed, with the reason
        return {"k": k, "error": str(exc)}
    m = measure(plan)
    return {"k": k, "findings": findings, "n_ok_agrees": m.n_ok_agrees,
            "start_end": m.start_end.tolist(), "in_slowdown": m.in_slowdown.tolist(),
            "target_distance_max": m.target_distance_max, "vertex_gap_max": m.vertex_gap_max}  # fmt: skip


def _worst(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The worst figures over the polylines' rows (:func:`run_one`)."""
    done = [r for r in rows if "error" not in r]
    ratios = [np.asarray(r["start_end"]).reshape(-1, 2) for r in done]
    slow = [np.asarray(r["in_slowdown"], dtype=bool).reshape(-1, 2) for r in done]
    free = np.concatenate([x[~s] for x, s in zip(ratios, slow, strict=True)] + [np.ones(1)])
    held = np.concatenate([x[s] for x, s in zip(ratios, slow, strict=True)] + [np.ones(0)])
    return {
        "failed": [r["k"] for r in rows if "error" in r or r["findings"] or not r["n_ok_agrees"]],
        "errors": [f"{r['k']}: {r['error']}" for r in rows if "error" in r],
        "check_findings": sum(r.get("findings", 0) for r in done),
        "n_ok_disagrees": sum(not r["n_ok_agrees"] for r in done),
        "marks": sum(len(x) for x in ratios),
        "marks_in_slowdown": int(sum(s.any(axis=1).sum() for s in slow)),
        "end_ratio_min": float(free.min()),
        "end_ratio_max": float(free.max()),
        "end_ratio_min_in_slowdown": float(held.min()) if len(held) else None,
        "target_distance_max_m": max((r["target_distance_max"] for r in done), default=0.0),
        "vertex_gap_max_m": max((r["vertex_gap_max"] for r in done), default=0.0),
    }


def sweep(n: int, seed: int, workdir: Path, workers: int = 1) -> dict[str, Any]:
    """Plan ``n`` random polylines (seed ``seed``) on ``workers`` processes and collect the
    worst figures; each polyline's row goes to standard error as it is done."""
    import sys
    from concurrent.futures import ProcessPoolExecutor

    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(workers) as pool:
        for row in pool.map(run_one, range(n), [seed] * n, [workdir] * n):
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)  # progress: one row a polyline
    return {"polylines": n, "seed": seed, **_worst(rows), "seconds": time.perf_counter() - t0}


def command(
    polylines: Annotated[int, typer.Option(min=1, help="Random polylines to plan.")] = 200,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    workers: Annotated[int, typer.Option(min=1, help="Processes planning in parallel.")] = 1,
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON (last line).")] = False,
) -> None:
    """Random polylines with turns around corner_deg: worst mark-start/end speed ratio and
    worst target distance from the polyline, measured from each plan with numpy."""
    import tempfile

    from rich.console import Console
    from rich.table import Table

    with tempfile.TemporaryDirectory() as tmp:
        w = sweep(polylines, seed, Path(tmp), workers)
    table = Table(title=f"corners: {polylines} random polylines (seed {seed})")
    table.add_column("figure")
    table.add_column("value")
    slow = w["end_ratio_min_in_slowdown"]
    for label, value in (
        ("plans failing (check findings or n_ok)", f"{len(w['failed'])} {w['failed'][:10]}"),
        ("marks (with an end in a reported slowdown)", f"{w['marks']} ({w['marks_in_slowdown']})"),
        ("mark start/end speed, worst low", f"{100 * w['end_ratio_min']:.2f} %"),
        ("mark start/end speed, worst high", f"{100 * w['end_ratio_max']:.2f} %"),
        ("  in a reported slowdown, lowest", "-" if slow is None else f"{100 * slow:.2f} %"),
        ("target distance from the polyline, max", f"{1e3 * w['target_distance_max_m']:.4f} mm"),
        ("vertex distance from its target, max", f"{1e3 * w['vertex_gap_max_m']:.4f} mm"),
        ("time", f"{w['seconds']:.0f} s"),
    ):
        table.add_row(label, value)
    Console().print(table)
    if as_json:
        print(json.dumps({"bench": "corners", **w}))
