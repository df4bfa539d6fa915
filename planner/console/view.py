"""The viewer's starting camera: where the operator's browser looks from at first.

It looks at the middle of the scene objects (or the robots' bases without any) from the
fixed camera's side, a little farther back and higher, so the cloud the camera sees faces
the viewer.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.model.scene import SceneItem
from planner.model.system import System
from planner.model.transforms import Array

#: vertical field of view of the viewer (rad)
VIEW_FOV = np.radians(50.0)
#: the viewer stands this many times the camera's distance from the look-at point
PULL_BACK = 1.25
#: and this much higher (m)
RAISE = 0.25


class View(NamedTuple):
    """A viewer pose: ``position`` and ``look_at`` (world, m), ``up`` (+z), ``fov`` (rad,
    vertical)."""

    position: Array
    look_at: Array
    up: Array
    fov: float


def default_view(system: System, scene: list[SceneItem]) -> View:
    """The starting view of the page (see the module docstring)."""
    if scene:
        look = np.mean([i.world_T_object[:3, 3] for i in scene], axis=0)
    else:
        look = np.mean([r.world_T_base[:3, 3] for r in system.robots], axis=0)
    if system.camera is not None and system.camera.robot is None:
        eye = system.camera.world_T_camera[:3, 3]
    else:
        eye = look + np.array([-1.0, -1.0, 0.8])
    pos = look + PULL_BACK * (eye - look) + np.array([0.0, 0.0, RAISE])
    return View(pos, look, np.array([0.0, 0.0, 1.0]), float(VIEW_FOV))
