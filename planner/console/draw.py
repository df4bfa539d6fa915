"""Scene nodes of the console page (viser): the fixed geometry, the robots, lines, markers.

Everything is drawn in the scenario's world frame (m), z up. Robots are drawn with their
URDF's visual meshes where it has them (:mod:`planner.console.visuals`), else with the
planner's collision geometry (:class:`planner.safety.geometry.SafetyWorld`: link capsules);
the mirror plate and mount always with the latter. They are placed at the joints given to
:meth:`RobotDrawing.update`; the meshes are sent once and only their poses move afterwards.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.console.visuals import urdf_visual, wxyz
from planner.model.scene import SceneItem, object_mesh
from planner.model.system import System
from planner.model.transforms import Array

SCENE_COLOUR = (170, 170, 180)
KEEP_OUT_COLOUR = (230, 40, 40)
LINK_COLOUR = (150, 190, 235)
MIRROR_COLOUR = (230, 230, 250)
BEAM_COLOUR = (40, 40, 40)  # the live beam: dark, outside the cloud's colour ramp


def add_item(server: Any, name: str, item: SceneItem, colour: tuple[int, int, int],
             opacity: float | None = None) -> Any:  # fmt: skip
    """A scene object or keep-out volume as a mesh node (world frame)."""
    mesh = object_mesh(item)
    return server.scene.add_mesh_simple(
        name,
        np.asarray(mesh.vertices, dtype=np.float32),
        np.asarray(mesh.triangles, dtype=np.uint32),
        color=colour,
        opacity=opacity,
        flat_shading=True,
        side="double",
        cast_shadow=False,
        receive_shadow=False,
    )


def add_fixed(server: Any, system: System, scene: list[SceneItem], keep_out: list[SceneItem]
              ) -> None:  # fmt: skip
    """Grid, world axes, scene objects, keep-out volumes (translucent red), the laser and
    the fixed camera."""
    server.scene.add_grid(
        "/grid", width=2.0, height=2.0, cell_size=0.1, section_size=0.5, shadow_opacity=0.0
    )
    server.scene.add_frame("/world", axes_length=0.1, axes_radius=0.003)
    for item in scene:
        add_item(server, f"/scene/{item.name}", item, SCENE_COLOUR, opacity=0.35)
    for item in keep_out:
        add_item(server, f"/keep_out/{item.name}", item, KEEP_OUT_COLOUR, opacity=0.4)
    L = system.world_T_laser
    server.scene.add_frame("/laser", axes_length=0.05, axes_radius=0.003,
                           wxyz=wxyz(L[:3, :3]), position=L[:3, 3])  # fmt: skip
    server.scene.add_label("/laser/label", "laser", position=(0.0, 0.0, -0.02))
    if system.camera is not None and system.camera.robot is None:
        C = system.camera.world_T_camera
        server.scene.add_frame("/camera", axes_length=0.06, axes_radius=0.003,
                               wxyz=wxyz(C[:3, :3]), position=C[:3, 3])  # fmt: skip
        server.scene.add_label("/camera/label", "camera", position=(0.0, 0.0, 0.0))


class RobotDrawing:
    """The robots as viser meshes (see the module docstring), posed by :meth:`update`."""

    def __init__(self, server: Any, system: System) -> None:
        import trimesh

        from planner.safety.geometry import PartKind, SafetyWorld

        self.system = system
        self.visuals = {r.name: v for r in system.robots if (v := urdf_visual(server, r))}
        self.world = SafetyWorld(system, bare=True)
        self.nodes: list[tuple[int, Any]] = []
        for part in self.world.parts:
            if not part.on_robot:
                continue
            if part.kind is PartKind.LINK and system.robots[part.robot].name in self.visuals:
                continue
            g = self.world.geometry(part.index)
            if hasattr(g, "halfLength"):
                mesh = trimesh.creation.capsule(
                    height=2 * g.halfLength, radius=g.radius, count=[12, 12]
                )
            else:
                mesh = trimesh.creation.box(extents=2 * np.asarray(g.halfSide))
            colour = MIRROR_COLOUR if part.kind is PartKind.MIRROR else LINK_COLOUR
            node = server.scene.add_mesh_simple(
                f"/robots/{part.name}",
                np.asarray(mesh.vertices, dtype=np.float32),
                np.asarray(mesh.faces, dtype=np.uint32),
                color=colour,
                opacity=0.9 if part.kind is PartKind.MIRROR else None,
                cast_shadow=False,
                receive_shadow=False,
            )
            self.nodes.append((part.index, node))

    def update(self, q: dict[str, Array]) -> None:
        """Pose every part at joints ``q`` (rad per robot)."""
        self.world.update(self.system.stack_q(q))
        for name, visual in self.visuals.items():
            visual.update(q[name])
        for index, node in self.nodes:
            T = self.world.placement(index)
            node.wxyz = wxyz(T.getRotation())
            node.position = np.asarray(T.getTranslation(), dtype=float)


def polyline_segments(points: Array) -> Array:
    """A polyline (K x 3) as the (K - 1) x 2 x 3 segments viser's line nodes take."""
    P = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    if len(P) < 2:
        return np.zeros((0, 2, 3), dtype=np.float32)
    return np.stack([P[:-1], P[1:]], axis=1)


def set_lines(scene: Any, name: str, polylines: list[Array], colour: tuple[int, int, int],
              thickness: float = 2.0) -> Any:  # fmt: skip
    """Replace node ``name`` by the segments of ``polylines`` (screen-space thickness, px);
    removes it when there is nothing to draw."""
    segs = [polyline_segments(p) for p in polylines]
    segs = [s for s in segs if len(s)]
    if not segs:
        return scene.add_line_segments(name, np.zeros((1, 2, 3), np.float32), colour, visible=False)
    S = np.concatenate(segs)
    return scene.add_line_segments(name, S, colour, thickness=thickness,
                                   thickness_units="screen")  # fmt: skip
