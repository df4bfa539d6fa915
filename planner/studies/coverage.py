"""``beamrelay study coverage``: what N = 1, 2, 3 robots can light on an object.

Layout (world = the floor under the object, z up, metres): a sphere of radius 0.08 m at
``(0, 0, 0.35)``; a laser 1.3 m up on the object's axis pointing down; UR5e bases on the
floor at 0.55 m from the axis, at azimuths 0°, 120°, 240°, each facing the object. The
laser is on the object's axis, so any robot can put its mirror in the beam above the object.
The layout is defined here, in code (:func:`coverage_system`), not in a scenario file: the
study's geometry (mirror sites, sectors) is built around the sphere's centre and the bases'
azimuths, which a scenario does not carry as such.

With N robots, the beam may be relayed by any ordered sub-chain of them; the robots left
out are parked (:func:`planner.studies.coverage_safety.parked_q`, folded away from the
object) and stay in the cell as obstacles. A surface point counts as reached when some
sub-chain and relay geometry put the spot on it with every condition of a valid solution:
joint limits (closed-form IK per robot), front-face hits inside the ROI (by construction the
beam hits the mirror centre), incidence ≤ 60°, no occlusion by the object of the beam
segments (laser → mirror → ... → mirror → target; open3d raycasting on the object's mesh;
the last segment must meet the surface first at the target), and the product's safety rules
(:class:`planner.safety.Safety`, via :mod:`planner.studies.coverage_safety`): arm-arm
(parked arms included), arm-self and arm-object clearance, beam-arm (parked arms included),
keep-out and laser return. Each point is also counted without the safety rules
(``reached_geometric``), so the report shows what the rules take away and which rules.

Every point counted has a witness configuration that passes every rule, but the search only
samples relay geometries (hit distances on the laser ray, mirror centre positions around the
object, mirror spins, the IK branch nearest home, one parking posture), so coverage is a
lower bound of what the layout allows. The IK at a sampled relay geometry is
:func:`planner.studies.relay_geometry.mirror_ik` (closed-form helpers of :mod:`planner.ik`;
``ClosedForm.search`` picks its own hit points, see there).

Directions: the azimuths (10° sectors, 360° around the object) from which a beam reaches
some surface point at less than 60° from the horizontal.
"""
# long module: the coverage study's relay enumeration, safety filter and report share its geometry

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations, pairwise
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from planner.model.system import System
from planner.model.transforms import Array
from planner.studies import common
from planner.studies.relay_geometry import chain_system, laser_ray, mirror_ik, solve_chain, unit

if TYPE_CHECKING:  # the safety rules load Pinocchio and coal: imported when first used
    from planner.safety import Violation
    from planner.studies.coverage_safety import ChainRules

TRIALS = 400  # paper scale: the default of --trials and of `study all`
CENTER = np.array([0.0, 0.0, 0.35])
RADIUS = 0.08
BASE_RADIUS = 0.55
AZIMUTHS_DEG = (0.0, 120.0, 240.0)
MAX_INCIDENCE = np.deg2rad(60.0)
SECTOR_DEG = 10.0
PREFIXES_PER_HIT = 4
SPINS = tuple(np.linspace(0.0, 2 * np.pi, 6, endpoint=False))  # mirror rolls tried (rad)


def coverage_system(n: int = 3) -> System:
    """The layout of the module docstring with the first ``n`` robots."""
    from planner.model.build import build_system
    from planner.model.transforms import make_T, rot_x, rot_z

    bases = [
        make_T(rot_z(az + np.pi), [BASE_RADIUS * np.cos(az), BASE_RADIUS * np.sin(az), 0.0])
        for az in np.deg2rad(AZIMUTHS_DEG[:n])
    ]
    return build_system(make_T(rot_x(np.pi), [0.0, 0.0, 1.3]), bases, roi_margin=0.01)


def sphere_points(n: int, seed: int = 0) -> tuple[Array, Array]:
    """``n`` near-uniform surface points of the sphere (Fibonacci; ``seed`` != 0 rotates the
    set about z) and their outward normals."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k + (
        np.random.default_rng(seed).uniform(0, 2 * np.pi) if seed else 0
    )
    r = np.sqrt(1 - z**2)
    normals = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    return CENTER + RADIUS * normals, normals


def mirror_sites(system: System, robot: int) -> Array:
    """Candidate mirror centres for a relay robot: a shell around the object on its side."""
    az0 = np.deg2rad(AZIMUTHS_DEG[robot])
    sites = []
    for dist in (0.22, 0.32, 0.42):
        for el in np.deg2rad([-15.0, 10.0, 35.0, 60.0]):
            for daz in np.deg2rad([-60.0, -30.0, 0.0, 30.0, 60.0]):
                a = az0 + daz
                d = np.array([np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el)])
                sites.append(CENTER + dist * d)
    return np.array(sites)


@lru_cache(maxsize=4)
def _scene(radius: float) -> Any:
    """The object (a sphere of ``radius`` m about ``CENTER``) as a :class:`SceneModel`."""
    import open3d as o3d

    from planner.model.scene import SceneModel

    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=60)
    mesh.translate(CENTER)
    return SceneModel(meshes=[("object", mesh)])


def first_hits(origins: Array, ends: Array) -> Array:
    """Distance along each segment origin → end to the first object surface (inf: none)."""
    d = ends - origins
    return _scene(RADIUS).cast(origins, d / np.linalg.norm(d, axis=1, keepdims=True)).t


def clear(origins: Array, ends: Array, slack: float = 1e-3) -> Array:
    """Segments that do not touch the object (before ``slack`` of their end)."""
    length = np.linalg.norm(ends - origins, axis=1)
    return first_hits(origins, ends) > length - slack


@dataclass(frozen=True)
class Chain:
    """One ordered sub-chain and its feasible relays: for each candidate centre of the last
    mirror, up to ``PREFIXES_PER_HIT`` relays (the earlier hit points, laser side first;
    empty for a one-mirror chain) that bring the beam there."""

    robots: tuple[int, ...]
    sites: Array  # (S, 3) candidate centres of the last mirror
    prefixes: tuple[tuple[tuple[Array, ...], ...], ...]  # per site: relays


def sub_chains(n: int) -> list[tuple[int, ...]]:
    """Every ordered, non-empty subset of robots 0..n-1 (beam order = robot order)."""
    return [c for k in range(1, n + 1) for c in combinations(range(n), k)]


def build_chain(system: System, robots: tuple[int, ...]) -> Chain:
    """Feasible relay prefixes of a sub-chain (target independent)."""
    p0, v0 = laser_ray(system)
    first = [p0 + t * v0 for t in np.linspace(0.2, 0.75, 6)]
    # states: hit points so far (the last is the current mirror centre) and arriving beam
    states: list[tuple[tuple[Array, ...], Array]]
    states = [((h,), v0) for h in first if clear(p0[None], h[None])[0]]
    for j_prev, j in pairwise(robots):
        nxt: list[tuple[tuple[Array, ...], Array]] = []
        for s in mirror_sites(system, j):
            found = 0
            for hits, v_in in states:
                if found >= PREFIXES_PER_HIT:
                    break
                if not clear(hits[-1][None], s[None])[0]:
                    continue
                v_out = unit(s - hits[-1])
                if _mirror_ik(system, j_prev, hits[-1], v_in, v_out) is not None:
                    nxt.append(((*hits, s), v_out))
                    found += 1
        states = nxt
    sites: list[Array] = []
    prefixes: list[list[tuple[Array, ...]]] = []
    for hits, _ in states:
        for i, t in enumerate(sites):
            if np.array_equal(t, hits[-1]):
                prefixes[i].append(hits[:-1])
                break
        else:
            sites.append(hits[-1])
            prefixes.append([hits[:-1]])
    return Chain(robots, np.array(sites).reshape(-1, 3), tuple(tuple(p) for p in prefixes))


def arriving(system: System, prefix: tuple[Array, ...], site: Array) -> Array:
    """Unit beam direction arriving at ``site`` after the relay ``prefix``."""
    return unit(site - prefix[-1]) if prefix else laser_ray(system)[1]


def _mirror_ik(system: System, robot: int, hit: Array, v_in: Array, v_out: Array) -> Array | None:
    if float(v_in @ v_out) > 1 - 1e-9:
        return None
    return mirror_ik(system.robots[robot], hit, v_in, v_out, SPINS)


class Relay(NamedTuple):
    """A relay onto a target: every hit point in chain order, the unit beam direction onto
    the target, and the safety rule it breaks (None: it breaks none)."""

    hits: tuple[Array, ...]
    direction: Array
    violation: Violation | None


def reach_target(
    system: System, chain: Chain, target: Array, normal: Array, rules: ChainRules | None = None
) -> list[Relay]:
    """Relays for one target, at most one per candidate last-mirror centre: the first of its
    prefixes that breaks none of ``rules`` (:mod:`planner.studies.coverage_safety`), else
    the first geometrically feasible one with the rule it breaks."""
    if len(chain.sites) == 0:
        return []
    d = target - chain.sites
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cos_inc = -(d @ normal)
    ok = cos_inc >= np.cos(MAX_INCIDENCE)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return []
    t_hit = first_hits(chain.sites[idx], np.repeat(target[None], len(idx), 0))
    dist = np.linalg.norm(target - chain.sites[idx], axis=1)
    idx = idx[np.abs(t_hit - dist) < 2e-3]
    laser, sub = laser_ray(system)[0], chain_system(system, chain.robots)
    out = []
    for i in idx:
        unsafe: Relay | None = None
        for prefix in chain.prefixes[i]:
            hits = (*prefix, chain.sites[i])
            q = solve_chain(sub, hits, target, SPINS)
            if q is None:
                continue
            bad = None if rules is None else rules.violation(q, hits, target, laser)
            if bad is None:
                out.append(Relay(hits, d[i], None))
                break
            unsafe = unsafe or Relay(hits, d[i], bad)
        else:
            if unsafe is not None:
                out.append(unsafe)
    return out


def targets_job(n_robots: int, points: Array, normals: Array, ids: Array) -> list[dict[str, Any]]:
    """Reachability of some surface points in the cells of N = 1 .. ``n_robots`` robots by
    every sub-chain of each (one parallel job): reached with the safety rules applied (the
    cell's other robots parked), and geometrically (every other condition) alone."""
    system = coverage_system(n_robots)
    chains = _chains(n_robots)
    rows = []
    for n in range(1, n_robots + 1):
        for k in ids:
            for chain in (c for c in chains if max(c.robots) < n):
                rules = _rules(n, chain.robots)
                relays = reach_target(system, chain, points[k], normals[k], rules)
                rows.append(_row(n, int(k), chain, relays))
    return rows


def _row(n: int, point: int, chain: Chain, relays: list[Relay]) -> dict[str, Any]:
    """The CSV row of one point, sub-chain and cell of ``n`` robots."""
    from planner.studies.coverage_safety import rule_name

    safe = [r for r in relays if r.violation is None]
    broken = sorted({rule_name(r.violation) for r in relays if r.violation is not None})
    return {
        "N": n,
        "point": point,
        "chain": "-".join(map(str, chain.robots)),
        "reached": int(bool(safe)),
        "reached_geometric": int(bool(relays)),
        "broken": "; ".join(broken) if not safe else "",
        "azimuths_deg": " ".join(
            f"{np.degrees(np.arctan2(u[1], u[0])) % 360:.1f}"
            for u in (-r.direction for r in safe)
            if abs(u[2]) < np.sin(MAX_INCIDENCE)
        ),
    }


@lru_cache(maxsize=16)
def _rules(n_robots: int, robots: tuple[int, ...]) -> ChainRules:
    from planner.studies.coverage_safety import chain_rules

    return chain_rules(coverage_system(n_robots), robots, CENTER, RADIUS)


@lru_cache(maxsize=4)
def _chains(n_robots: int) -> tuple[Chain, ...]:
    system = coverage_system(n_robots)
    return tuple(build_chain(system, c) for c in sub_chains(n_robots))


def run(
    trials: int = TRIALS,
    seed: int = 0,
    workers: int | None = None,
    scheduler: str | None = None,
    n_max: int = 3,
) -> tuple[Array, Array, list[dict[str, Any]]]:
    """``trials`` surface points, reachability per sub-chain (parallel over point chunks)."""
    points, normals = sphere_points(trials, seed)
    chunks = np.array_split(
        np.arange(trials), max(1, min(trials, 4 * (workers or common.default_workers())))
    )
    jobs = [(n_max, points, normals, c) for c in chunks if len(c)]
    per = common.parallel_map(
        targets_job, jobs, workers=workers, scheduler=scheduler, label="coverage"
    )
    return points, normals, [r for rows in per for r in rows]


def summarize(points: Array, rows: list[dict[str, Any]], n_max: int = 3) -> list[dict[str, Any]]:
    """Per N: fraction of surface points and of 10° azimuth sectors reached."""
    out = []
    n_sectors = round(360 / SECTOR_DEG)
    for n in range(1, n_max + 1):
        sel = [r for r in rows if r["N"] == n]
        reached = {r["point"] for r in sel if r["reached"]}
        geometric = {r["point"] for r in sel if r["reached_geometric"]}
        lost = geometric - reached  # reachable but only by relays that break a rule
        broken = {c for r in sel if r["point"] in lost for c in r["broken"].split("; ") if c}
        sectors = {int(float(a) // SECTOR_DEG) for r in sel for a in r["azimuths_deg"].split() if a}
        out.append(
            {
                "N": n,
                "points_reached": len(reached),
                "points": len(points),
                "surface_fraction": len(reached) / len(points),
                "points_geometric": len(geometric),
                "rules_broken": "; ".join(sorted(broken)) or "-",
                "sectors_reached": len(sectors),
                "direction_fraction": len(sectors) / n_sectors,
            }
        )
    return out


def reached_mask(points: Array, rows: list[dict[str, Any]], n: int) -> Array:
    mask = np.zeros(len(points), bool)
    for r in rows:
        if r["N"] == n and r["reached"]:
            mask[r["point"]] = True
    return mask


def plot(points: Array, rows: list[dict[str, Any]], path: Path, n_max: int = 3) -> None:
    """Coverage maps (azimuth/elevation of each surface point) per N, plus direction sectors."""
    plt = common.pyplot()
    rel = (points - CENTER) / RADIUS
    az = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360
    el = np.degrees(np.arcsin(np.clip(rel[:, 2], -1, 1)))
    fig = plt.figure(figsize=(4 * n_max, 6.4))
    for n in range(1, n_max + 1):
        ax = fig.add_subplot(2, n_max, n)
        m = reached_mask(points, rows, n)
        ax.scatter(
            az[np.logical_not(m)], el[np.logical_not(m)], s=6, c="lightgray", label="not reached"
        )
        ax.scatter(az[m], el[m], s=6, c="tab:red", label="reached")
        for a in AZIMUTHS_DEG[:n]:
            ax.axvline(a, color="k", lw=0.6, ls=":")
        ax.set_title(f"N = {n}: {m.mean() * 100:.0f}% of the surface")
        ax.set_xlabel("surface azimuth (deg; dotted: robot bases)")
        ax.set_ylabel("surface elevation (deg)")
        ax.set_xlim(0, 360)
        pax = fig.add_subplot(2, n_max, n_max + n, projection="polar")
        sel = [r for r in rows if r["N"] == n]
        angles = [float(a) for r in sel for a in r["azimuths_deg"].split() if a]
        bins = np.arange(0, 361, SECTOR_DEG)
        hist, _ = np.histogram(angles, bins=bins)
        pax.bar(
            np.deg2rad(bins[:-1] + SECTOR_DEG / 2),
            (hist > 0).astype(float),
            width=np.deg2rad(SECTOR_DEG),
            color="tab:red",
            alpha=0.7,
        )
        pax.set_yticks([])
        pax.set_title(f"beam azimuths, {np.mean(hist > 0) * 100:.0f}% of 360°", fontsize=9)
    fig.axes[0].legend(fontsize=7, loc="lower left")
    common.save_figure(fig, path, dpi=80)


def write(out: Path, points: Array, rows: list[dict[str, Any]], trials: int, seed: int) -> dict:
    """CSV, plot and report.md; returns the ``--json`` figures."""
    summary = summarize(points, rows)
    plot(points, rows, common.out_dir(out) / "coverage.png")
    lines = [
        "# Coverage of an object's surface with N = 1, 2, 3 robots",
        "",
        f"Sphere r = {RADIUS * 1000:.0f} mm at {CENTER.tolist()} m, {trials} surface points "
        f"(seed {seed}); laser overhead pointing down; UR5e bases at {BASE_RADIUS} m, azimuths "
        f"{', '.join(f'{a:g}°' for a in AZIMUTHS_DEG)}. Reached = some ordered sub-chain of the N "
        "robots lights the point with joint limits, ROI, incidence ≤ 60°, no occlusion by the "
        "object (open3d raycasting of every beam segment) and the product's safety rules "
        "(`planner.safety.Safety`: arm-arm, arm-self and arm-object clearance 10 mm, beam-arm, "
        "keep-out, laser return), the robots left out of the sub-chain parked folded away "
        "from the object and checked as obstacles (arm-arm and beam-arm). Without the safety rules: "
        "the same without the safety rules; rules broken: those that removed the points "
        "reached only geometrically. Every point counted has a configuration passing every "
        "rule, but relay geometries are sampled: a lower bound. Details in "
        "`planner/studies/coverage.py` and `planner/studies/coverage_safety.py`.",
        "",
    ]
    header = ["N", "surface reached", "without the safety rules", "rules broken",
              "azimuth sectors reached (10°, beam < 60° from horizontal)"]  # fmt: skip
    row = "{N} | {surface_fraction:.1%} ({points_reached}/{points}) "
    row += "| {geometric_fraction:.1%} ({points_geometric}/{points}) | {rules_broken} "
    row += "| {direction_fraction:.0%} ({sectors_reached}/36) | {paper}"
    paper = {1: "N = 1 experiments only"}
    cells = [{**s, "paper": paper.get(s["N"], "motivation only (no figure)"),
              "geometric_fraction": s["points_geometric"] / s["points"]} for s in summary]  # fmt: skip
    lines += common.table_lines([*header, "paper"], cells, row)
    tables = {"coverage.csv": rows, "summary.csv": summary}
    common.write_report(out, [*lines, ""], tables, image=("coverage maps", "coverage.png"))
    return {"study": "coverage", "trials": trials, "seed": seed, "summary": summary}


def main(trials: int, seed: int, out: Path, workers: int | None, sched: str | None) -> dict:
    """Surface and beam-direction coverage of a sphere by N = 1, 2, 3 robots."""
    points, _, rows = run(trials, seed, workers, sched)
    return write(out, points, rows, trials, seed)


command = common.study_command(main, TRIALS, Path("reports/coverage"))
