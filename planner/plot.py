"""3D matplotlib pictures: robots' mirror poses, beam paths and targets (world frame, metres).

:func:`plot_beam_chain` draws one or several configurations (``make demo`` uses it for the
README picture); :func:`plot_plan` draws a plan.json document's solutions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from planner.ik.evaluate import evaluate, mirror_poses
from planner.system import System, Targets
from planner.transforms import Array

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")


def _mirror_corners(world_T_mirror: Array, size: tuple[float, float]) -> Array:
    w, h = size[0] / 2, size[1] / 2
    local = np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]])
    return local @ world_T_mirror[:3, :3].T + world_T_mirror[:3, 3]


def _draw_config(ax: Any, system: System, q: Array, target: Array, alpha: float) -> Array:
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    ev = evaluate(system, q, target)
    path = np.vstack([system.world_T_laser[:3, 3], ev.hits, ev.spot])
    ax.plot(*path.T, color="red", lw=0.8, alpha=alpha)
    for i, (r, M) in enumerate(zip(system.robots, mirror_poses(system, q), strict=True)):
        col = _COLOURS[i % len(_COLOURS)]
        quad = Poly3DCollection([_mirror_corners(M, r.mirror.size)], alpha=0.35 * alpha + 0.1)
        quad.set_facecolor(col)
        ax.add_collection3d(quad)
        flange = M @ np.linalg.inv(r.mirror.flange_T_mirror)
        base = r.world_T_base[:3, 3]
        ax.plot(*np.vstack([base, flange[:3, 3]]).T, color=col, lw=1.0, alpha=0.3 * alpha)
    return path


def plot_beam_chain(
    system: System,
    q: Array | list[Array],
    targets: Targets | Array,
    path: str | Path,
    title: str = "",
    max_beams: int = 25,
) -> None:
    """Draw configurations ``q`` (one stacked vector or a list, one per target) with the laser,
    robot bases, mirrors, beam paths and all targets; save to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = targets.points if isinstance(targets, Targets) else np.atleast_2d(targets)
    qs = [q] if isinstance(q, np.ndarray) and q.ndim == 1 else list(q)
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*points.T, s=2, color="black", alpha=0.4, label="targets")
    laser = system.world_T_laser[:3, 3]
    ax.scatter(*laser, marker="*", s=120, color="red", label="laser")
    for i, r in enumerate(system.robots):
        ax.scatter(*r.world_T_base[:3, 3], marker="s", s=60, color=_COLOURS[i % 4], label=r.name)
    pick: Any = (
        np.unique(np.linspace(0, len(qs) - 1, min(max_beams, len(qs))).astype(int)) if qs else []
    )
    drawn = [points, laser[None], *[r.world_T_base[:3, 3][None] for r in system.robots]]
    for k in pick:
        aim = points[min(k, len(points) - 1)]
        drawn.append(_draw_config(ax, system, qs[k], aim, 0.8 if len(qs) == 1 else 0.5))
    pts = np.vstack(drawn)
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    span = float(np.ptp(pts, axis=0).max()) / 2 + 0.05
    ax.set_xlim(centre[0] - span, centre[0] + span)
    ax.set_ylim(centre[1] - span, centre[1] + span)
    ax.set_zlim(max(centre[2] - span, -0.1), centre[2] + span)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_plan(system: System, targets: Targets, plan: dict[str, Any], path: str | Path) -> None:
    """Draw a plan document: every target, and the beam of a spread of solved targets."""
    qs, pts = [], []
    for sol in plan["solutions"]:
        if sol["status"] == "ok":
            qs.append(system.stack_q(sol["q"]))
            pts.append(targets.points[sol["target"]])
    m = plan["metrics"]
    title = f"{plan['scenario'].get('name') or ''}: {m['n_ok']}/{m['n_targets']} targets solved"
    if not qs:
        plot_beam_chain(system, [], targets, path, title)
        return
    # one beam per drawn configuration, aimed at its own target
    order = np.argsort([np.linalg.norm(p) for p in pts])
    plot_beam_chain(system, [qs[i] for i in order], np.array([pts[i] for i in order]), path, title)
