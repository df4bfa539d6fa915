"""The checker's safety setup of a plan: the geometry and settings every safety check of
:mod:`planner.verify.safety` reads (robots with the checker's own kinematics and shapes,
laser, camera, scene and keep-out volumes, clearances), and the violation record
(:class:`Hit`). World frame, metres, radians.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from planner.model.transforms import Array
from planner.verify.arm_models import checker_arm
from planner.verify.numpy_beam import pose_matrix
from planner.verify.safety_shapes import Shape, volume
from planner.verify.urdf import UrdfChain

#: the conventions' factor on the calibration's spot uncertainty in the safety margin
UNCERTAINTY_K = 3.0


class Hit(NamedTuple):
    """A violation at configuration ``row``: check name, the parts, distance and bound (m),
    and the plan status reason it stands for."""

    row: int
    check: str
    what: str
    value: float
    bound: float
    reason: str


@dataclass
class Setup:
    """The plan's safety geometry and settings (see the module docstring)."""

    robots: list[dict[str, Any]]
    laser: Array
    camera: dict[str, Any] | None
    scene: list[Shape]
    keep: list[Shape]
    clearance: float
    cone: float
    radius: float
    unchecked: list[str]
    margin: float = 0.0

    @classmethod
    def from_plan(cls, plan: dict[str, Any], base_dir: Path,
                  urdfs: Mapping[Path, UrdfChain] | None = None) -> Setup:  # fmt: skip
        """The setup of a plan document (relative mesh and URDF paths from ``base_dir``; a
        URDF already read, in ``urdfs`` by its path, is not read again)."""
        scn = plan["scenario"]
        sys_ = scn["system"]
        safety = scn.get("safety") or {}
        robots, unchecked = [], []
        for r in sys_["robots"]:
            urdf = None
            if r.get("urdf"):
                path = Path(r["urdf"])
                path = path if path.is_absolute() else base_dir / path
                known = None if urdfs is None else urdfs.get(path)
                urdf = UrdfChain(path) if known is None else known
            entry = cls.robot(r["name"], pose_matrix(r.get("world_T_base") or {}),
                              pose_matrix(r["mirror"].get("flange_T_mirror") or {}),
                              r["mirror"]["size"], r.get("model"), urdf)  # fmt: skip
            if urdf is not None or (entry["arm"] is not None and entry["arm"].shapes is None):
                unchecked.append(str(r["name"]))
            robots.append(entry)
        cam = sys_.get("camera")
        camera = None
        if cam is not None:
            key = "world_T_camera" if cam.get("world_T_camera") else "flange_T_camera"
            camera = {"robot": cam.get("robot"), "T": pose_matrix(cam[key], "camera")}
        scene = [volume(d, base_dir, f"scene[{i}]") for i, d in enumerate(scn.get("scene") or [])]
        keep = [volume(d, base_dir, f"keep_out[{i}]")
                for i, d in enumerate(scn.get("keep_out") or [])]  # fmt: skip
        return cls(robots, pose_matrix(sys_["laser"]["world_T_laser"]), camera, scene, keep,
                   float(safety.get("clearance", 0.01)),
                   float(np.radians(safety.get("return_cone_deg", 10.0))),
                   float(safety.get("return_radius", 0.01)), unchecked,
                   float(sys_["laser"].get("beam_radius") or 0.0)
                   + UNCERTAINTY_K * float(safety.get("spot_uncertainty") or 0.0))  # fmt: skip

    def shapes(self, Q: dict[str, Array]) -> list[list[Shape]]:
        """Per robot its shapes at joint rows Q[name] ([] for a robot whose twin has none,
        or a URDF robot: reported unchecked)."""
        return [r["arm"].shapes(r["base"], Q[r["name"]], r["mirror"], r["size"])
                if r["arm"] is not None and r["arm"].shapes is not None else []
                for r in self.robots]  # fmt: skip

    def mirrors(self, Q: dict[str, Array]) -> list[Array]:
        return [r["base"] @ self.flange(r, Q) @ r["mirror"] for r in self.robots]

    @staticmethod
    def robot(
        name: str, base: Array, mirror: Array, size: Any, model: str | None = None,
        urdf: UrdfChain | None = None,
    ) -> dict[str, Any]:  # fmt: skip
        """One robot's entry of ``robots``: the checker's reading of its ``urdf``, else its
        ``model``'s checker twin (None: the UR5e); base and mirror poses, mirror size (m)."""
        arm = None if urdf is not None else checker_arm(model)
        return {"name": name, "arm": arm, "urdf": urdf, "base": base, "mirror": mirror,
                "size": np.asarray(size, dtype=float)}  # fmt: skip

    @staticmethod
    def flange(r: dict[str, Any], Q: dict[str, Array]) -> Array:
        """``base_T_flange`` (M x 4 x 4) of robot ``r`` at its joint rows ``Q[name]``, by the
        checker's twin of its model or its own reading of the robot's URDF."""
        rows = np.atleast_2d(Q[r["name"]])
        if r["urdf"] is not None:
            return np.array([r["urdf"].fk(q) for q in rows]).reshape(len(rows), 4, 4)
        if r["arm"] is None:
            raise ValueError(f"{r['name']}: no independent kinematics to check it with")
        return r["arm"].fk(rows)
