"""The checker's independent numpy rules (planner.verify.safety) applied to configurations
the planner produced, for the safety tests."""

from __future__ import annotations

import numpy as np

from planner.model.system import System
from planner.model.transforms import Array
from planner.safety.shapes import Volume
from planner.verify.safety import Hit, Setup, arm_hits, beam_hits, target_hits
from planner.verify.safety_shapes import Shape


def _shape(v: Volume) -> Shape:
    if v.shape == "sphere":
        return Shape(v.name, "sphere", A=v.world_T_object[None, :3, 3], r=v.dims[0])
    if v.shape == "box":
        return Shape(v.name, "box", T=v.world_T_object[None], ext=np.array(v.dims))
    raise ValueError(v.shape)


def setup(system: System, scene: tuple[Volume, ...] = (), keep: tuple[Volume, ...] = (),
          clearance: float = 0.01) -> Setup:  # fmt: skip
    robots = [Setup.robot(r.name, r.world_T_base, r.mirror.flange_T_mirror, r.mirror.size)
              for r in system.robots]  # fmt: skip
    cam = None
    if system.camera is not None:
        cam = {"robot": None, "T": system.camera.world_T_camera}
    return Setup(robots, system.world_T_laser, cam, [_shape(v) for v in scene],
                 [_shape(v) for v in keep], clearance, np.radians(10.0), 0.01, [])  # fmt: skip


def hits(s: Setup, system: System, q: Array, beam: Array | None = None,
         target: Array | None = None) -> list[Hit]:  # fmt: skip
    """Every rule the configuration q (stacked) breaks, by the numpy geometry; ``beam`` is
    the polyline laser -> hits -> spot."""
    Q = {n: v[None] for n, v in system.split_q(np.asarray(q, dtype=float)).items()}
    out, _ = arm_hits(s, Q)
    if beam is not None:
        out += beam_hits(s, Q, np.asarray(beam, dtype=float)[None])
    if target is not None:
        out += target_hits(s, np.asarray(target, dtype=float)[None])
    return out
