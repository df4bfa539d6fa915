"""A robot's URDF visual meshes on the console page (yourdfpy through viser's ViserUrdf).

Used for a robot whose URDF has ``<visual>`` elements (a ``urdf:``/``model:`` file of the
scenario with meshes or primitives); the shipped UR5e URDF has none, so it is drawn with the
planner's collision geometry instead (:class:`planner.console.draw.RobotDrawing`). The URDF's
root link is placed at ``world_T_base @ base_T_universe``; joint angles are mapped by name.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from planner.model.system import Robot
from planner.model.transforms import Array


def wxyz(R: Array) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    from viser import transforms as vtf

    q = vtf.SO3.from_matrix(np.asarray(R, dtype=float)).wxyz
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def has_visuals(path: Path) -> bool:
    """Whether the URDF file at ``path`` gives any link a ``<visual>`` (False if unreadable)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return False
    return any(link.find("visual") is not None for link in root.iter("link"))


class UrdfVisual:
    """One robot's visual meshes under ``/robots/<name>/urdf``, posed by :meth:`update`.
    ValueError when the URDF's actuated joints are not the robot model's joints."""

    def __init__(self, server: Any, robot: Robot, path: Path) -> None:
        import yourdfpy
        from viser.extras import ViserUrdf

        urdf = yourdfpy.URDF.load(
            path, build_scene_graph=True, load_meshes=True,
            filename_handler=partial(yourdfpy.filename_handler_magic, dir=path.parent),
        )  # fmt: skip
        self.root_name = f"/robots/{robot.name}/urdf"
        T = robot.world_T_base @ robot.kinematics.base_T_universe
        self.root = server.scene.add_frame(self.root_name, wxyz=wxyz(T[:3, :3]),
                                           position=T[:3, 3], show_axes=False)  # fmt: skip
        self.view = ViserUrdf(server, urdf, root_node_name=self.root_name)
        names = list(robot.joint_names)
        try:
            self.order = [names.index(n) for n in self.view.get_actuated_joint_names()]
        except ValueError as exc:
            self.view.remove()
            raise ValueError(f"URDF joints {self.view.get_actuated_joint_names()} are not "
                             f"the model's {tuple(names)}") from exc  # fmt: skip

    def update(self, q: Array) -> None:
        """Pose the meshes at the robot's joints ``q`` (rad, the model's order)."""
        self.view.update_cfg(np.asarray(q, dtype=float)[self.order])


def urdf_visual(server: Any, robot: Robot) -> UrdfVisual | None:
    """The visual meshes of ``robot`` when its URDF has them and they load, else None."""
    path = Path(robot.kinematics.source)
    if path.suffix != ".urdf" or not has_visuals(path):
        return None
    try:
        return UrdfVisual(server, robot, path)
    except (ValueError, OSError):
        return None
