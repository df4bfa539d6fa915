"""Scene objects, keep-out volumes and failed targets for the 3D plan picture (world frame,
metres): boxes and cylinders as wireframes, spheres as translucent surfaces, meshes as their
vertices, failed targets as red crosses with one legend entry per failure reason."""

from __future__ import annotations

import itertools
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from planner.model.transforms import Array
from planner.verify.numpy_beam import pose_matrix


def _box_lines(T: Array, ext: Array) -> list[Array]:
    h = np.asarray(ext, dtype=float) / 2
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    C = (signs * h) @ T[:3, :3].T + T[:3, 3]
    return [C[[i, j]] for i in range(8) for j in range(i + 1, 8)
            if np.sum(signs[i] != signs[j]) == 1]  # fmt: skip


def _cylinder_lines(T: Array, r: float, h: float, n: int = 24) -> list[Array]:
    a = np.linspace(0.0, 2 * np.pi, n + 1)
    rings = [
        np.column_stack([r * np.cos(a), r * np.sin(a), np.full_like(a, z)]) for z in (-h / 2, h / 2)
    ]
    lines = [ring @ T[:3, :3].T + T[:3, 3] for ring in rings]
    for k in range(0, n, n // 6):
        lines.append(np.array([rings[0][k], rings[1][k]]) @ T[:3, :3].T + T[:3, 3])
    return lines


def _sphere(ax: Any, c: Array, r: float, colour: str) -> Array:
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 18), np.linspace(0, np.pi, 10))
    X = c[0] + r * np.cos(u) * np.sin(v)
    Y = c[1] + r * np.sin(u) * np.sin(v)
    Z = c[2] + r * np.cos(v)
    ax.plot_surface(X, Y, Z, color=colour, alpha=0.25, linewidth=0)
    return np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])


def draw_volumes(ax: Any, items: list[dict[str, Any]], colour: str, label: str) -> list[Array]:
    """Draw resolved ``scene`` or ``keep_out`` entries; returns the points drawn."""
    drawn: list[Array] = []
    for n, d in enumerate(items):
        T = pose_matrix(d.get("world_T_object") or {}, label)
        lines: list[Array] = []
        if d.get("box") is not None:
            lines = _box_lines(T, np.asarray(d["box"], dtype=float))
        elif d.get("cylinder") is not None:
            lines = _cylinder_lines(T, float(d["cylinder"][0]), float(d["cylinder"][1]))
        elif d.get("sphere") is not None:
            drawn.append(_sphere(ax, T[:3, 3], float(d["sphere"]), colour))
        elif d.get("mesh") is not None:
            drawn.append(_mesh_points(d, T))
            ax.scatter(*drawn[-1].T, s=0.5, color=colour, alpha=0.3)
        for line in lines:
            ax.plot(*line.T, color=colour, lw=1.0, alpha=0.8)
        drawn += lines
        ax.text(*T[:3, 3], f" {d.get('name', '')}", color=colour, fontsize=7)
        if n == 0:
            ax.plot([], [], color=colour, lw=3, label=label)
    return drawn


def _mesh_points(d: dict[str, Any], T: Array, most: int = 2000) -> Array:
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(Path(d["mesh"]))
    V = np.asarray(mesh.vertices, dtype=float) * float(d.get("scale") or 1.0)
    V = V[:: max(1, len(V) // most)] if len(V) else np.zeros((1, 3))
    return V @ T[:3, :3].T + T[:3, 3]


def draw_failed(ax: Any, plan: dict[str, Any], points: Array) -> list[Array]:
    """Failed targets as red crosses, one legend entry per reason; returns their points."""
    failed = [s for s in plan["solutions"] if s["status"] != "ok"]
    if not failed:
        return []
    reasons = Counter(str(s.get("reason")) for s in failed)
    markers = dict(zip(sorted(reasons), itertools.cycle("xX+1*"), strict=False))
    for reason, count in sorted(reasons.items()):
        P = points[[int(s["target"]) for s in failed if str(s.get("reason")) == reason]]
        ax.scatter(*P.T, marker=markers[reason], s=30, color="red",
                   label=f"failed: {reason} ({count})")  # fmt: skip
    return [points[[int(s["target"]) for s in failed]]]


def target_marker_size(n: int) -> float:
    """Marker area (pt^2) of ``n`` targets: large for a few, small but visible for 10^4."""
    return float(np.clip(3000.0 / max(n, 1), 6.0, 60.0))


def draw_camera(ax: Any, world_T_camera: Array, fx: float, fy: float, width: int, height: int,
                depth: float = 0.12) -> Array:  # fmt: skip
    """The camera as its viewing frustum (OpenCV optical frame, +z forward) cut ``depth`` m in
    front of it, and a marker at its centre; returns the points drawn (world, m)."""
    T = np.asarray(world_T_camera, dtype=float)
    hx, hy = depth * width / (2 * fx), depth * height / (2 * fy)
    corners = np.array([[-hx, -hy, depth], [hx, -hy, depth], [hx, hy, depth], [-hx, hy, depth]])
    world = corners @ T[:3, :3].T + T[:3, 3]
    centre = T[:3, 3]
    for c in world:
        ax.plot(*np.stack([centre, c]).T, color="tab:purple", lw=1.0)
    ring = np.vstack([world, world[:1]])
    ax.plot(*ring.T, color="tab:purple", lw=1.0)
    ax.scatter(*centre, marker="D", s=50, color="tab:purple", label="camera", depthshade=False)
    return np.vstack([centre[None], world])
