"""The UR5e collision geometry again, for the independent checker: its own capsule table,
its own forward kinematics of every link frame (standard DH), the mirror plate and mount
boxes, and the pairwise distances between robots, within a robot and against boxes and
spheres. No coal, no Pinocchio.

Link frame i (1..6) is the DH frame i-1 turned by q_i: ``F_i = A_1 ... A_{i-1} Rz(q_i)``
with ``A_j = Rz(q_j) Tz(d_j) Tx(a_j) Rx(alpha_j)``; link 0 is the base. Capsule endpoints
are in those frames; everything returned is in the world frame, metres. The numbers are
UR's published UR5e collision meshes enclosed by capsules (see the planner's table; a test
asserts the two tables agree).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.model.transforms import Array
from planner.verify.distances import box_box, capsule_box, capsule_capsule
from planner.verify.numpy_beam import UR5E_A, UR5E_ALPHA, UR5E_D

#: (name, link, a, b, radius), m, link frames as above
CAPSULES: tuple[
    tuple[str, int, tuple[float, float, float], tuple[float, float, float], float], ...
] = (
    ("base", 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.050), 0.076),
    ("shoulder", 1, (0.0, -0.013, 0.145), (0.0, -0.013, 0.162), 0.085),
    ("upper_arm_shoulder", 2, (0.0, 0.0, 0.090), (0.0, 0.0, 0.182), 0.061),
    ("upper_arm", 2, (0.0, 0.0, 0.138), (-0.425, 0.0, 0.138), 0.054),
    ("upper_arm_elbow", 2, (-0.425, 0.0, 0.076), (-0.425, 0.0, 0.182), 0.061),
    ("forearm_elbow", 3, (0.0, 0.0, -0.010), (0.0, 0.0, 0.030), 0.066),
    ("forearm", 3, (0.0, 0.0, 0.007), (-0.3922, 0.0, 0.007), 0.049),
    ("forearm_wrist", 3, (-0.3922, 0.0, -0.027), (-0.3922, 0.0, 0.048), 0.040),
    ("wrist_1", 4, (0.0, 0.0, 0.111), (0.0, 0.0, 0.133), 0.066),
    ("wrist_2", 5, (0.0, -0.009, 0.096), (0.0, 0.013, 0.096), 0.058),
)
#: (name, link, centre, full extents), m, link frame axes
BOXES = (("wrist_3", 6, (0.0, -0.003, 0.0766), (0.076, 0.082, 0.0462)),)
#: link pairs the checker skips: their envelopes touch at every configuration
SELF_EXCLUDED = {("wrist_1", "wrist_3"), ("wrist_3", "wrist_1")}
#: m: mirror plate thickness, mount block width, gap between mount and plate
MIRROR_THICKNESS, MOUNT_WIDTH, MOUNT_GAP = 0.006, 0.05, 0.0005


def link_frames(q: Array) -> Array:
    """Frames (8, 4, 4) in the robot base frame at joints ``q`` (rad): the base, links 1..6,
    then the flange (tool0), by standard DH."""
    q = np.asarray(q, dtype=float)
    out = [np.eye(4)]
    T = np.eye(4)
    for i in range(6):
        c, s = np.cos(q[i]), np.sin(q[i])
        Rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        out.append(T @ Rz)
        ca, sa = np.cos(UR5E_ALPHA[i]), np.sin(UR5E_ALPHA[i])
        rest = np.array(
            [[1, 0, 0, UR5E_A[i]], [0, ca, -sa, 0], [0, sa, ca, UR5E_D[i]], [0, 0, 0, 1.0]]
        )
        T = T @ Rz @ rest
    out.append(T)
    return np.array(out)


@dataclass(frozen=True)
class ArmShapes:
    """One robot's geometry at one configuration, world frame: capsules ``(name, a, b, r,
    link)`` and boxes ``(name, world_T_box, extents, link)`` (wrist_3, mirror plate, mount;
    the plate and mount are on link 7 here, the flange)."""

    capsules: list[tuple[str, Array, Array, float, int]]
    boxes: list[tuple[str, Array, Array, int]]


def arm_shapes(
    world_T_base: Array, q: Array, flange_T_mirror: Array, size: tuple[float, float]
) -> ArmShapes:
    """Capsules and boxes (wrist_3, mirror plate, mount) of a UR5e at joints ``q`` (rad); the
    plate is a flat mirror's (a plan file describes flat mirrors, conventions section 3)."""
    F = world_T_base @ link_frames(q)
    caps = []
    for name, link, a, b, r in CAPSULES:
        T = F[link]
        caps.append((name, T[:3, :3] @ a + T[:3, 3], T[:3, :3] @ b + T[:3, 3], r, link))
    boxes: list[tuple[str, Array, Array, int]] = []
    for name, link, centre, ext in BOXES:
        C = np.eye(4)
        C[:3, 3] = centre
        boxes.append((name, F[link] @ C, np.array(ext), link))
    w_T_f = F[7]
    plate = np.eye(4)
    plate[2, 3] = -MIRROR_THICKNESS / 2
    thin = np.array([size[0], size[1], MIRROR_THICKNESS])
    boxes.append(("mirror", w_T_f @ flange_T_mirror @ plate, thin, 7))
    back = flange_T_mirror @ np.array([0.0, 0.0, -MIRROR_THICKNESS, 1.0])
    height = back[2] - MOUNT_GAP
    if height > 1e-3:
        M = np.eye(4)
        M[:3, 3] = [back[0], back[1], height / 2]
        boxes.append(("mount", w_T_f @ M, np.array([MOUNT_WIDTH, MOUNT_WIDTH, height]), 7))
    return ArmShapes(caps, boxes)


def _items(arm: ArmShapes) -> list[tuple[str, str, tuple]]:
    items: list[tuple[str, str, tuple]] = [("capsule", c[0], c) for c in arm.capsules]
    return items + [("box", b[0], b) for b in arm.boxes]


def _dist(x: tuple[str, str, tuple], y: tuple[str, str, tuple]) -> float:
    (kx, _, gx), (ky, _, gy) = x, y
    if kx == "capsule" and ky == "capsule":
        return capsule_capsule(gx[1], gx[2], gx[3], gy[1], gy[2], gy[3])[0]
    if kx == "capsule":
        return capsule_box(gx[1], gx[2], gx[3], gy[1], gy[2])
    if ky == "capsule":
        return capsule_box(gy[1], gy[2], gy[3], gx[1], gx[2])
    return box_box(gx[1], gx[2], gy[1], gy[2])


def arm_arm_distances(a: ArmShapes, b: ArmShapes) -> dict[tuple[str, str], float]:
    """Distance (m) of every part of arm a to every part of arm b, keyed by part names."""
    return {(x[1], y[1]): _dist(x, y) for x in _items(a) for y in _items(b)}


def arm_self_distances(arm: ArmShapes) -> dict[tuple[str, str], float]:
    """Distances (m) between link shapes two or more links apart (but the pairs in
    :data:`SELF_EXCLUDED`), and of the mirror plate and mount (link 7) to every link shape
    but wrist_3's (link 6), which carries them."""
    items = _items(arm)
    links = [g[4] if k == "capsule" else g[3] for k, _, g in items]
    out = {}
    for i, x in enumerate(items):
        for j in range(i + 1, len(items)):
            y, la, lb = items[j], links[i], links[j]
            if (x[1], y[1]) in SELF_EXCLUDED or (la == 7 and lb == 7):
                continue
            if (7 in (la, lb) and min(la, lb) < 6) or (7 not in (la, lb) and abs(la - lb) >= 2):
                out[(x[1], y[1])] = _dist(x, y)
    return out
