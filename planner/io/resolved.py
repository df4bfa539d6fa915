"""A loaded scenario as one plain mapping: the ``scenario`` section of plan.json.

Every default filled in, every pose a ``{matrix: 4x4}`` (metres, world frame), includes
applied and file paths absolute, so a plan file is self-contained.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from planner.io.scenario import (
    LIMIT_KEYS,
    LoadedScenario,
    keep_out_objects,
    scene_objects,
    system_from_scenario,
)
from planner.model.robots import DEFAULT_MODEL
from planner.model.scene import SceneItem
from planner.model.system import System
from planner.model.transforms import Array
from schemas.scenario import System as SystemModel


def _pose(T: Array) -> dict[str, Any]:
    return {"matrix": np.asarray(T, dtype=float).tolist()}


def _model_key(
    model: str | None, urdf: str | None, source: str, scn: LoadedScenario
) -> dict[str, str]:
    """``{model: ur5e}``, or ``{urdf: absolute path}`` for a URDF robot and for a registered
    model built from a URDF file (so the checker can re-verify it with its own kinematics),
    else ``{model: name}``."""
    if urdf is not None:
        return {"urdf": str(scn.resolve_path(urdf))}
    name = model or DEFAULT_MODEL
    if name != DEFAULT_MODEL and source.endswith(".urdf") and Path(source).is_file():
        return {"urdf": str(Path(source).resolve())}
    return {"model": name}


def _system_dict(system: System, model: SystemModel, scn: LoadedScenario) -> dict[str, Any]:
    robots = []
    for r, rm in zip(system.robots, model.robots, strict=True):
        kind = _model_key(rm.model, rm.urdf, r.kinematics.source, scn)
        limits = {k: getattr(r.limits, k).tolist() for k in LIMIT_KEYS}
        mirror = {
            "flange_T_mirror": _pose(r.mirror.flange_T_mirror),
            "size": list(r.mirror.size),
            "roi_margin": r.mirror.roi_margin,
        }
        robots.append(
            {"name": r.name, **kind, "world_T_base": _pose(r.world_T_base)}
            | {"home": r.home.tolist(), "limits": limits, "mirror": mirror}
        )
    laser = {"world_T_laser": _pose(system.world_T_laser)}
    laser |= model.laser.model_dump(include={"power", "gate"}, exclude_none=True)
    out: dict[str, Any] = {"laser": laser, "robots": robots}
    if system.camera is not None:
        k = system.camera.intrinsics
        intrinsics = {"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy}
        intrinsics |= {"cx": k.cx, "cy": k.cy}
        cam = system.camera
        mount: dict[str, Any] = {"world_T_camera": _pose(cam.world_T_camera)}
        if cam.robot is not None and cam.flange_T_camera is not None:
            mount = {"robot": cam.robot, "flange_T_camera": _pose(cam.flange_T_camera)}
        out["camera"] = mount | {"intrinsics": intrinsics}
    return out


def _item_dict(item: SceneItem) -> dict[str, Any]:
    """A scene object or keep-out volume as resolved YAML (pose as a matrix, mesh absolute)."""
    shape: dict[str, Any]
    if item.shape == "box":
        shape = {"box": np.asarray(item.extents).tolist()}
    elif item.shape == "sphere":
        shape = {"sphere": item.radius}
    elif item.shape == "cylinder":
        shape = {"cylinder": [item.radius, item.height]}
    else:
        shape = {"mesh": str(item.mesh_path), "scale": item.scale}
    out = {"name": item.name, **shape, "world_T_object": _pose(item.world_T_object)}
    if item.motion is not None:
        out["motion"] = item.motion.to_dict()
    return out


def resolved_scenario_dict(scn: LoadedScenario) -> dict[str, Any]:
    """The validated scenario with defaults filled in and every pose as ``{matrix: 4x4}``.

    Includes are already applied (``include: []``); ``urdf`` and ``mesh`` paths are
    absolute; ``truth.system`` (if any) is the full merged truth system. Validates again as
    a :class:`~schemas.scenario.Scenario` (plan.json ``scenario``).
    """
    m = scn.model
    out: dict[str, Any] = {
        "name": scn.name,
        "system": _system_dict(system_from_scenario(scn), m.system, scn),
        "scene": [_item_dict(item) for item in scene_objects(scn)],
        "keep_out": [_item_dict(item) for item in keep_out_objects(scn)],
        "safety": m.safety.model_dump(),
        "targets": m.targets.model_dump(exclude_none=True),
        "solver": m.solver.model_dump(),
        "trajectory": m.trajectory.model_dump(),
        "include": [],
    }
    out["system"]["laser"]["beam_radius"] = m.system.laser.beam_radius  # the safety margin
    if scn.truth_system is not None:
        truth = system_from_scenario(scn, truth=True)
        out["truth"] = {"system": _system_dict(truth, scn.truth_system, scn)}
    return out
