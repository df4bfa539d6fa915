"""The checker's own safety geometry of a plan, for many configurations at once (numpy).

Arms: the UR5e capsules and boxes of :mod:`planner.verify.arms` (its own table), placed by
a batched standard-DH forward kinematics of every link frame. Volumes: the resolved
scenario's ``scene`` objects and ``keep_out`` volumes as spheres, boxes, cylinders or (for a
keep-out mesh) the half-spaces of its convex hull. Distances between them come from
:mod:`planner.verify.batch_distances`; pairs whose bounding spheres are far apart are not
measured. World frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from planner.model.transforms import Array
from planner.verify import arms
from planner.verify import batch_distances as bd
from planner.verify.numpy_beam import UR5E_A, UR5E_ALPHA, UR5E_D, pose_matrix


def link_frames_batch(Q: Array) -> Array:
    """Frames (M, 8, 4, 4) in the robot base frame at joints Q (M, 6): base, links 1..6
    (DH frame i-1 turned by q_i), flange."""
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    M = len(Q)
    out = np.empty((M, 8, 4, 4))
    T = np.tile(np.eye(4), (M, 1, 1))
    out[:, 0] = T
    for i in range(6):
        c, s = np.cos(Q[:, i]), np.sin(Q[:, i])
        Rz = np.tile(np.eye(4), (M, 1, 1))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1] = c, -s, s, c
        T = T @ Rz
        out[:, i + 1] = T
        ca, sa = np.cos(UR5E_ALPHA[i]), np.sin(UR5E_ALPHA[i])
        rest = np.array([[1, 0, 0, UR5E_A[i]], [0, ca, -sa, 0], [0, sa, ca, UR5E_D[i]],
                         [0, 0, 0, 1.0]])  # fmt: skip
        T = T @ rest
    out[:, 7] = T
    return out


@dataclass(frozen=True)
class Shape:
    """One solid for M configurations: ``kind`` capsule (``A``, ``B`` (M, 3), ``r``), box
    (``T`` (M, 4, 4), ``ext`` (3,)), sphere (``A`` centre, ``r``), cylinder (``T``, ``r``,
    ``h`` along z) or hull (``planes`` (F, 4), ``A`` a centre, ``r`` bounding radius).
    Frozen: its bounding spheres are computed once, however many pairs it is measured in."""

    name: str
    kind: str
    link: int = -1
    A: Array = field(default_factory=lambda: np.zeros((1, 3)))
    B: Array = field(default_factory=lambda: np.zeros((1, 3)))
    r: float = 0.0
    T: Array = field(default_factory=lambda: np.eye(4)[None])
    ext: Array = field(default_factory=lambda: np.zeros(3))
    h: float = 0.0
    planes: Array = field(default_factory=lambda: np.zeros((0, 4)))

    @cached_property
    def sphere(self) -> tuple[Array, Array]:
        """Bounding spheres: centres (M, 3) and radius (m)."""
        if self.kind == "capsule":
            return (self.A + self.B) / 2, np.linalg.norm(self.B - self.A, axis=-1) / 2 + self.r
        if self.kind == "box":
            return self.T[..., :3, 3], np.full(len(self.T), np.linalg.norm(self.ext) / 2)
        if self.kind == "cylinder":
            return self.T[..., :3, 3], np.full(len(self.T), np.hypot(self.r, self.h / 2))
        return self.A, np.full(len(self.A), self.r)

    def rows(self, idx: Any) -> Shape:
        """The shape at configurations ``idx`` only (fixed shapes are returned as they are)."""
        if self.kind == "capsule":
            return Shape(self.name, self.kind, self.link, self.A[idx], self.B[idx], self.r)
        if self.kind == "box" and len(self.T) > 1:
            return Shape(self.name, self.kind, self.link, T=self.T[idx], ext=self.ext)
        return self


def arm_shapes(world_T_base: Array, Q: Array, flange_T_mirror: Array, size: Array) -> list[Shape]:
    """A UR5e's capsules and boxes (wrist_3, mirror plate, mount; plate and mount on link 7)
    at joints Q (M, 6), world frame."""
    F = world_T_base @ link_frames_batch(Q)
    out = []
    for name, link, a, b, r in arms.CAPSULES:
        R, p = F[:, link, :3, :3], F[:, link, :3, 3]
        out.append(Shape(name, "capsule", link, R @ np.array(a) + p, R @ np.array(b) + p, r))
    for name, link, centre, ext in arms.BOXES:
        C = np.eye(4)
        C[:3, 3] = centre
        out.append(Shape(name, "box", link, T=F[:, link] @ C, ext=np.array(ext)))
    plate = np.eye(4)
    plate[2, 3] = -arms.MIRROR_THICKNESS / 2
    out.append(Shape("mirror", "box", 7, T=F[:, 7] @ flange_T_mirror @ plate,
                     ext=np.array([size[0], size[1], arms.MIRROR_THICKNESS])))  # fmt: skip
    back = flange_T_mirror @ np.array([0.0, 0.0, -arms.MIRROR_THICKNESS, 1.0])
    height = back[2] - arms.MOUNT_GAP
    if height > 1e-3:
        Mt = np.eye(4)
        Mt[:3, 3] = [back[0], back[1], height / 2]
        out.append(Shape("mount", "box", 7, T=F[:, 7] @ Mt,
                         ext=np.array([arms.MOUNT_WIDTH, arms.MOUNT_WIDTH, height])))  # fmt: skip
    return out


def volume(d: dict[str, Any], base_dir: Path, where: str) -> Shape:
    """A resolved ``scene`` or ``keep_out`` entry as a fixed shape (a mesh: its convex hull)."""
    T = pose_matrix(d.get("world_T_object") or {}, where)
    name = str(d.get("name", where))
    if d.get("sphere") is not None:
        return Shape(name, "sphere", A=T[None, :3, 3], r=float(d["sphere"]))
    if d.get("box") is not None:
        return Shape(name, "box", T=T[None], ext=np.asarray(d["box"], dtype=float))
    if d.get("cylinder") is not None:
        r, h = (float(x) for x in d["cylinder"])
        return Shape(name, "cylinder", T=T[None], r=r, h=h)
    import open3d as o3d
    from scipy.spatial import ConvexHull

    path = Path(d["mesh"])
    mesh = o3d.io.read_triangle_mesh(path if path.is_absolute() else base_dir / path)
    V = np.asarray(mesh.vertices, dtype=float) * float(d.get("scale") or 1.0)
    if len(V) < 4:
        raise ValueError(f"{where}: mesh {path} has no volume")
    W = V @ T[:3, :3].T + T[:3, 3]
    centre = W.mean(axis=0)
    radius = float(np.linalg.norm(W - centre, axis=1).max())
    return Shape(name, "hull", A=centre[None], r=radius, planes=ConvexHull(W).equations)


def distance(a: Shape, b: Shape) -> Array:
    """Distances (M,) between two shapes: negative (the radii minus the axes' distance) where
    a rounded shape overlaps, 0 where a segment or box meets a box; ``b`` may be fixed (a
    scene object). Cylinders: the distance to the enclosing box and capsule, whichever is larger
    (a lower bound of the true distance)."""
    if a.kind == "box" and b.kind == "capsule":
        a, b = b, a
    if b.kind == "cylinder":
        return np.maximum(distance(a, _cylinder_box(b)), distance(a, _cylinder_axis(b)))
    if a.kind == "capsule":
        if b.kind == "capsule":
            return bd.segment_segment(a.A, a.B, b.A, b.B) - a.r - b.r
        if b.kind == "box":
            return bd.segment_box(a.A, a.B, b.T, b.ext) - a.r
        if b.kind == "sphere":
            return bd.point_segment(b.A, a.A, a.B) - a.r - b.r
    if a.kind == "box":
        if b.kind == "box":
            return bd.box_box(a.T, a.ext, b.T, b.ext)
        if b.kind == "sphere":
            return bd.point_box(b.A, a.T, a.ext) - b.r
    raise ValueError(f"no distance between a {a.kind} and a {b.kind}")


def cylinder_inner(c: Shape) -> Shape:
    """The box inscribed in a cylinder (r sqrt 2 square, full height): distances to it
    bound the true distance from above."""
    side = c.r * np.sqrt(2.0)
    return Shape(c.name, "box", T=c.T, ext=np.array([side, side, c.h]))


def _cylinder_box(c: Shape) -> Shape:
    return Shape(c.name, "box", T=c.T, ext=np.array([2 * c.r, 2 * c.r, c.h]))


def _cylinder_axis(c: Shape) -> Shape:
    half = c.T[:, :3, 2] * (c.h / 2)
    return Shape(c.name, "capsule", A=c.T[:, :3, 3] - half, B=c.T[:, :3, 3] + half, r=c.r)


def near_distances(a: Shape, b: Shape, within: float) -> Array:
    """Distances (M,) of a to b, measured only where their bounding spheres are closer than
    ``within`` (m); +inf elsewhere."""
    ca, ra = a.sphere
    cb, rb = b.sphere
    lower = np.linalg.norm(ca - cb, axis=-1) - ra - rb
    M = max(len(np.atleast_1d(lower)), 1)
    out = np.full(M, np.inf)
    idx = np.flatnonzero(np.broadcast_to(lower, (M,)) < within)
    if len(idx):
        out[idx] = distance(a.rows(idx), b.rows(idx))
    return out
