"""Forward kinematics of a serial URDF arm in plain numpy, for the independent checker.

Written from the URDF format (``<joint>``: ``<origin xyz rpy>``, ``<axis xyz>``, type
revolute | prismatic | fixed), not taken from the planner's Pinocchio model, so a URDF robot
is re-checked by separate code. Joint order matches Pinocchio's: depth first from the root
link, children by joint name. ``base_T_flange`` is in metres; joints in rad (revolute) or m
(prismatic).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NamedTuple

import numpy as np

from planner.errors import InputError
from planner.model.transforms import Array, inv_T, make_T, rpy_to_matrix

MOVABLE = ("revolute", "prismatic")


class _Joint(NamedTuple):
    name: str
    kind: str
    parent: str
    child: str
    parent_T_joint: Array
    axis: Array


def _floats(text: str | None, default: tuple[float, ...]) -> Array:
    return np.array(default if text is None else [float(x) for x in text.split()], dtype=float)


def _joint(el: ET.Element, source: str) -> _Joint:
    name, kind = el.get("name", "?"), el.get("type", "?")
    if kind not in (*MOVABLE, "fixed"):
        raise InputError(f"joint {name!r} of type {kind} is not supported", source)
    parent, child, origin = el.find("parent"), el.find("child"), el.find("origin")
    if parent is None or child is None:
        raise InputError(f"joint {name!r} lacks its parent or child link", source)
    xyz = _floats(None if origin is None else origin.get("xyz"), (0.0, 0.0, 0.0))
    rpy = _floats(None if origin is None else origin.get("rpy"), (0.0, 0.0, 0.0))
    axis_el = el.find("axis")
    axis = _floats(None if axis_el is None else axis_el.get("xyz"), (1.0, 0.0, 0.0))
    norm = float(np.linalg.norm(axis))
    if kind in MOVABLE and not norm > 0:
        raise InputError(f"joint {name!r} has a zero axis", source)
    T = make_T(rpy_to_matrix(rpy), xyz)
    return _Joint(
        name, kind, parent.get("link", ""), child.get("link", ""), T, axis / max(norm, 1e-300)
    )


def _axis_rotation(axis: Array, angle: float) -> Array:
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


class UrdfChain:
    """``base_T_flange(q)`` of a URDF arm (frames are link names)."""

    def __init__(self, path: str | Path, *, base: str = "base", flange: str = "tool0") -> None:
        source = str(path)
        try:
            root = ET.parse(path).getroot()
        except (OSError, ET.ParseError) as exc:
            raise InputError(f"cannot read URDF: {exc}", source) from None
        joints = [_joint(el, source) for el in root.iter("joint")]
        children = {j.child for j in joints}
        links = [el.get("name", "") for el in root.iter("link")]
        roots = [name for name in links if name not in children]
        if len(roots) != 1:
            raise InputError(f"expected one root link, found {roots}", source)
        for frame in (base, flange):
            if frame not in links:
                raise InputError(f"frame {frame!r} not in the robot model", source)
        self._joints = {j.child: j for j in joints}
        self.movable = [j.name for j in _dfs(roots[0], joints) if j.kind in MOVABLE]
        self.nq = len(self.movable)
        self.base, self.flange = base, flange

    def link_pose(self, link: str, q: Array) -> Array:
        """``root_T_link`` at joints ``q`` (nq,)."""
        T = np.eye(4)
        while link in self._joints:
            j = self._joints[link]
            motion = np.eye(4)
            if j.kind in MOVABLE:
                qj = float(q[self.movable.index(j.name)])
                if j.kind == "revolute":
                    motion[:3, :3] = _axis_rotation(j.axis, qj)
                else:
                    motion[:3, 3] = j.axis * qj
            T = j.parent_T_joint @ motion @ T
            link = j.parent
        return T

    def fk(self, q: Array) -> Array:
        """``base_T_flange`` (4 x 4, m) at joints ``q`` (nq,)."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.nq,):
            raise InputError(f"expected {self.nq} joint values, got shape {q.shape}")
        return inv_T(self.link_pose(self.base, q)) @ self.link_pose(self.flange, q)


def _dfs(root: str, joints: list[_Joint]) -> list[_Joint]:
    out: list[_Joint] = []
    for j in sorted((j for j in joints if j.parent == root), key=lambda j: j.name):
        out.append(j)
        out += _dfs(j.child, joints)
    return out
