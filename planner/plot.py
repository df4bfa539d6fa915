"""Matplotlib pictures of plans (world frame; metres, radians, seconds).

:func:`plot_beam_chain` draws configurations in 3D: each arm as the chain of its joint
origins (Pinocchio FK of every joint), the mirror as a square patch, the beam from the laser
through every mirror to the spot (``make demo`` uses it for the README picture).
:func:`plot_plan` draws a plan.json document's solutions that way, with the scene objects (grey), the keep-out
volumes (red) and the failed targets (red crosses, one legend entry per reason). :func:`plot_profiles`
draws the timed trajectory: joint profiles (q, qd and qdd as % of the limits) vs t, the spot
trace against the target path, the fluence along the marked path (power / speed, J/m; the
marked speed without a power) and the spot's deviation (or the move durations for points).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from planner.beam.trace import mirror_poses, trace_beam
from planner.model.status import Status
from planner.model.system import System, Targets
from planner.model.transforms import Array, inv_T
from planner.plot_scene import draw_camera, draw_failed, draw_volumes, target_marker_size
from planner.verify.marking import marked_speeds
from planner.verify.spot import arrival_mask, segment_mask
from planner.verify.trajectory import _plane_spots, nearest_spots, spot_deviation

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
_SEGMENT_COLOURS = {"approach": "0.92", "move": "0.92", "path": "#e3f2e1", "dwell": "#fdf0d5",
                    "run_in": "#e6eefa", "run_out": "#e6eefa"}  # fmt: skip


def arm_points(system: System, q: Array) -> list[Array]:
    """Per robot, the world points base origin -> joint origins -> flange (stacked ``q``)."""
    out, i = [], 0
    for r in system.robots:
        local = np.vstack([np.zeros(3), r.kinematics.joint_origins(q[i : i + r.nq])])
        out.append(local @ r.world_T_base[:3, :3].T + r.world_T_base[:3, 3])
        i += r.nq
    return out


def _mirror_corners(world_T_mirror: Array, size: tuple[float, float]) -> Array:
    w, h = size[0] / 2, size[1] / 2
    local = np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]])
    return local @ world_T_mirror[:3, :3].T + world_T_mirror[:3, 3]


def _draw_config(
    ax: Any, system: System, q: Array, target: Array, alpha: float, arms: bool
) -> Array:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    ev = trace_beam(system, q, target)
    path = np.vstack([system.world_T_laser[:3, 3], ev.hits, ev.spot])
    ax.plot(*path.T, color="red", lw=0.8, alpha=alpha)
    drawn = [path]
    for i, (r, M) in enumerate(zip(system.robots, mirror_poses(system, q), strict=True)):
        col = _COLOURS[i % len(_COLOURS)]
        quad = Poly3DCollection([_mirror_corners(M, r.mirror.size)], alpha=0.35 * alpha + 0.25)
        quad.set_facecolor(col)
        quad.set_edgecolor("k")
        quad.set_linewidth(0.3)
        ax.add_collection3d(quad)
        flange = (M @ inv_T(r.mirror.flange_T_mirror))[:3, 3]
        ax.plot(*np.vstack([flange, M[:3, 3]]).T, color=col, lw=1.0, alpha=alpha)
    if arms:
        for i, pts in enumerate(arm_points(system, q)):
            col = _COLOURS[i % len(_COLOURS)]
            ax.plot(*pts.T, color=col, lw=3.0, alpha=0.85, solid_capstyle="round")
            ax.scatter(*pts[1:-1].T, color="k", s=10, depthshade=False)
            drawn.append(pts)
    return np.vstack(drawn)


def plot_beam_chain(
    system: System,
    q: Array | list[Array],
    targets: Targets | Array,
    path: str | Path,
    title: str = "",
    max_beams: int = 25,
    overlay: Callable[[Any], list[Array]] | None = None,
) -> None:
    """Draw configurations ``q`` (one stacked vector or a list, one per target) with the laser,
    the arms (joint chains of one representative configuration), mirrors, beam paths and all
    targets; ``overlay(ax)`` draws more (scene, keep-out, failed targets) and returns the
    points it drew (for the axis limits); save to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = targets.points if isinstance(targets, Targets) else np.atleast_2d(targets)
    qs = [q] if isinstance(q, np.ndarray) and q.ndim == 1 else list(q)
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*points.T, s=target_marker_size(len(points)), color="tab:blue", alpha=0.9,
               edgecolors="k", linewidths=0.3, depthshade=False, label="targets")  # fmt: skip
    laser = system.world_T_laser[:3, 3]
    ax.scatter(*laser, marker="*", s=120, color="red", label="laser")
    for i, r in enumerate(system.robots):
        ax.scatter(*r.world_T_base[:3, 3], marker="s", s=60, color=_COLOURS[i % 4], label=r.name)
    pick: Any = (
        np.unique(np.linspace(0, len(qs) - 1, min(max_beams, len(qs))).astype(int)) if qs else []
    )
    drawn = [points, laser[None], *[r.world_T_base[:3, 3][None] for r in system.robots]]
    if system.camera is not None:
        k = system.camera.intrinsics
        world_T_camera = system.camera.world_T_camera  # eye-in-hand: at the home joints
        drawn.append(draw_camera(ax, world_T_camera, k.fx, k.fy, k.width, k.height))
    show_arms = pick[len(pick) // 2] if len(pick) else -1
    for k in pick:
        aim = points[min(k, len(points) - 1)]
        alpha = 0.8 if len(qs) == 1 else 0.5
        drawn.append(_draw_config(ax, system, qs[k], aim, alpha, arms=k == show_arms))
    if overlay is not None:
        drawn += overlay(ax)
    pts = np.vstack(drawn)
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    span = float(np.ptp(pts, axis=0).max()) / 2 + 0.05
    ax.set_xlim(centre[0] - span, centre[0] + span)
    ax.set_ylim(centre[1] - span, centre[1] + span)
    ax.set_zlim(max(centre[2] - span, -0.1), centre[2] + span)
    ax.set_box_aspect((1, 1, (centre[2] + span - max(centre[2] - span, -0.1)) / (2 * span)))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_plan(system: System, targets: Targets, plan: dict[str, Any], path: str | Path) -> None:
    """Draw a plan document: every target, and the beam of a spread of solved targets."""
    qs, pts = [], []
    for sol in plan["solutions"]:
        if sol["status"] == Status.OK:
            qs.append(system.stack_q(sol["q"]))
            pts.append(targets.points[sol["target"]])
    m = plan["metrics"]
    title = f"{plan['scenario'].get('name') or ''}: {m['n_ok']}/{m['n_targets']} targets solved"

    def overlay(ax: Any) -> list[Array]:

        scn = plan["scenario"]
        drawn = draw_volumes(ax, scn.get("scene") or [], "0.55", "scene")
        drawn += draw_volumes(ax, scn.get("keep_out") or [], "red", "keep-out")
        drawn += draw_failed(ax, plan, targets.points)
        return drawn

    if not qs:
        plot_beam_chain(system, [], targets, path, title, overlay=overlay)
        return
    # one beam per drawn configuration, aimed at its own target
    order = np.argsort([np.linalg.norm(p) for p in pts])
    plot_beam_chain(system, [qs[i] for i in order], np.array([pts[i] for i in order]), path,
                    title, overlay=overlay)  # fmt: skip


def profiles_path(plot: str | Path) -> Path:
    """Where :func:`plot_profiles` goes next to a ``--plot`` file: ``plan.png`` ->
    ``plan_profiles.png``."""
    p = Path(plot)
    return p.with_name(f"{p.stem}_profiles{p.suffix or '.png'}")


def _plane_axes(points: Array) -> tuple[Array, Array, Array]:
    """Centroid and the two principal directions of a point set (for a 2D view)."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c) if len(points) > 1 else (None, None, np.eye(3))
    return c, vt[0], vt[1]


def _shade(ax: Any, t: Array, segments: list[dict[str, Any]]) -> None:
    """Shade the segments' time spans by kind: one filled area per kind (any count)."""

    for kind in sorted({s["kind"] for s in segments}):
        mask = segment_mask(t, segments, kind)
        ax.fill_between(t, 0, 1, where=mask, transform=ax.get_xaxis_transform(), lw=0,
                        color=_SEGMENT_COLOURS.get(kind, "white"))  # fmt: skip


def _arrival_spots(system: System, plan: dict[str, Any], targets: Targets, Q: Array, p: Array,
                   v: Array) -> Array:  # fmt: skip
    """The spot of each arrival (joints ``Q``, last rays ``p``, ``v``) on the plane of the
    solved target whose configuration is nearest (a k-d tree: linear in the targets)."""
    from scipy.spatial import cKDTree

    solved = [s for s in plan["solutions"] if s["status"] == Status.OK]
    ids = np.array([int(s["target"]) for s in solved])
    _, j = cKDTree(np.array([system.stack_q(s["q"]) for s in solved])).query(Q)
    k = ids[np.asarray(j, dtype=int)]
    nrm = None if targets.normals is None else targets.normals[k]
    return _plane_spots(p, v, targets.points[k], nrm)


def _fluence_panel(ax: Any, plan: dict[str, Any]) -> None:
    """Fluence (J/m = power / spot speed) along the marked length (mm), or the marked spot
    speed (mm/s) when the scenario gives no laser power."""

    speeds = marked_speeds(plan)
    if speeds is None:
        return
    v, _, s = speeds
    power = ((plan["scenario"].get("system") or {}).get("laser") or {}).get("power")
    if power is None:
        ax.plot(1e3 * s, 1e3 * v, "g.", ms=1)
        ax.set_ylabel("marked speed (mm/s)")
        ax.set_title(f"spot speed while the laser is on: {1e3 * v.min():.3f} - "
                     f"{1e3 * v.max():.3f} mm/s", fontsize=9)  # fmt: skip
    else:
        fluence = float(power) / np.maximum(v, 1e-12)
        ax.plot(1e3 * s, fluence, "g.", ms=1)
        ax.set_ylabel("fluence (J/m)")
        ax.set_title(f"fluence {fluence.min():.4g} - {fluence.max():.4g} J/m at "
                     f"{1e3 * float(power):g} mW (max/min {fluence.max() / fluence.min():.4f})",
                     fontsize=9)  # fmt: skip
    ax.set_xlabel("marked length (mm)")
    ax.grid(alpha=0.3)


# long: one figure: joint panels, spot trace and deviation panel drawn in the order they appear
def plot_profiles(system: System, targets: Targets, plan: dict[str, Any], path: str | Path) -> None:
    """Joint profiles (q rad; qd, qdd in % of each joint's limit) vs t with the segments
    shaded, the spot trace vs the target path (mm, in the targets' principal plane) and the
    spot deviation (µm) on a path, or the move durations for points; save to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from planner.plan.timed import spot_rays

    traj = plan["trajectory"]
    t = np.asarray(traj["t"], dtype=float)
    segments = traj.get("segments", [])
    fig = plt.figure(figsize=(13, 8.5))
    grid = fig.add_gridspec(3, 2, width_ratios=(1.6, 1.0))
    axes = [fig.add_subplot(grid[i, 0]) for i in range(3)]
    for ax in axes[1:]:
        ax.sharex(axes[0])
    scales = [None, "velocity", "acceleration"]
    labels = ["q (rad)", "qd (% of limit)", "qdd (% of limit)"]
    for i, r in enumerate(system.robots):
        style = ("-", "--", ":", "-.")[i % 4]
        for key, ax, lim in zip(("q", "qd", "qdd"), axes, scales, strict=True):
            X = np.asarray(traj[key][r.name], dtype=float)
            if lim is not None:
                X = 100 * X / getattr(r.limits, lim)[None, :]
            for j in range(X.shape[1]):
                name = f"{r.name}.{r.kinematics.joint_names[j].replace('_joint', '')}"
                ax.plot(t, X[:, j], style, lw=0.9, color=f"C{j}", label=name)
    for ax, label in zip(axes, labels, strict=True):
        _shade(ax, t, segments)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[1:]:
        ax.axhline(100, color="r", lw=0.6, ls="--")
        ax.axhline(-100, color="r", lw=0.6, ls="--")
    axes[2].set_xlabel("t (s)")
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=6, fontsize=7, frameon=False)
    shades = {
        "path": "path green (laser on)",
        "dwell": "dwell amber (laser on)",
        "approach": "moves grey",
        "run_in": "run-in/out blue",
        "run_out": "run-in/out blue",
    }
    shown = {shades.get(s["kind"], "moves grey") for s in segments}
    axes[0].set_title(f"joint profiles (shaded: {', '.join(sorted(shown))})", fontsize=9)

    P = targets.points
    c, e1, e2 = _plane_axes(P)
    marks = targets.kind == "path" and bool(traj.get("laser_on"))
    ax_xy = fig.add_subplot(grid[0, 1] if marks else grid[0:2, 1])
    if marks:
        _fluence_panel(fig.add_subplot(grid[1, 1]), plan)
    if targets.kind == "path":
        ax_xy.plot(1e3 * (P - c) @ e1, 1e3 * (P - c) @ e2, "k-", lw=3, alpha=0.25,
                   label="target path")  # fmt: skip
    else:
        ax_xy.plot(1e3 * (P - c) @ e1, 1e3 * (P - c) @ e2, "k.", ms=3, alpha=0.4,
                   label="targets")  # fmt: skip
    ax_low = fig.add_subplot(grid[2, 1])
    on_path = segment_mask(t, segments, "path")
    Q = np.hstack([np.asarray(traj["q"][r.name], dtype=float) for r in system.robots])
    if targets.kind == "path" and on_path.any():
        p, v = spot_rays(system, Q[on_path])
        step = max(1, 2_000_000 // len(P))
        spots = np.vstack([nearest_spots(p[i : i + step], v[i : i + step], P, targets.normals)[1]
                           for i in range(0, len(p), step)])  # fmt: skip
        ax_xy.plot(1e3 * (spots - c) @ e1, 1e3 * (spots - c) @ e2, "r-", lw=0.8, label="spot")
        dev = spot_deviation(p, v, P, targets.normals, bool(targets.closed))
        ax_low.plot(t[on_path], 1e6 * dev, "r.", ms=1)
        ax_low.set_ylabel("spot deviation (µm)")
        ax_low.set_xlabel("t (s)")
        ax_low.set_title(f"max {1e3 * dev.max():.4f} mm", fontsize=9)
    else:
        ends = [s for s in segments if s["kind"] in ("approach", "move")]
        idx = np.flatnonzero(arrival_mask(t, segments))
        if len(idx):
            p, v = spot_rays(system, Q[idx])
            spots = _arrival_spots(system, plan, targets, Q[idx], p, v)
            ax_xy.plot(1e3 * (spots - c) @ e1, 1e3 * (spots - c) @ e2, "r-", lw=0.5,
                       alpha=0.6, label="spot, visit order")  # fmt: skip
        ax_low.bar(np.arange(len(ends)), [s["t1"] - s["t0"] for s in ends], width=1.0)
        ax_low.set_xlabel("move (visit order)")
        ax_low.set_ylabel("move time (s)")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.set_xlabel("along 1st principal axis (mm)")
    ax_xy.set_ylabel("along 2nd principal axis (mm)")
    ax_xy.set_title("spot trace vs targets", fontsize=9)
    ax_xy.legend(fontsize=8)
    ax_xy.grid(alpha=0.3)
    ax_low.grid(alpha=0.3)
    name = plan["scenario"].get("name") or ""
    fig.suptitle(f"{name}: trajectory {t[-1]:.2f} s at {1 / np.diff(t[:2])[0]:.0f} Hz"
                 if len(t) > 1 else name)  # fmt: skip
    rows = int(np.ceil(len(names) / 6))
    fig.tight_layout(rect=(0.0, 0.025 * rows + 0.01, 1.0, 1.0))
    fig.savefig(path, dpi=110)
    plt.close(fig)
