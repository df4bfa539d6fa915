"""The spot Jacobian on a target's surface plane, through the beam graph.

``spot_jacobian_function(kinematics, surfaces)`` (named ``servo_spot``, built once per chain
of robot models and mirror surfaces) takes the inputs of
:func:`planner.beam.graph.beam_function` and returns the spot on the plane through ``target``
normal to ``normal`` (world, m), its derivative with respect to every robot's joints stacked
(3 x nq, m/rad) and the last ray's unit direction.

:class:`SpotModel` binds it to one system (the *calibrated model*: its geometry is the one
the servo corrects) and expresses spot errors in the target's surface frame: the two in-plane
axes ``(e1, e2)`` of :func:`planner.model.transforms.plane_basis` of the normal. A target
without a normal gets the plane across the arriving beam (normal = minus the model's last
ray at the servo's start configuration), so its 2D error is the closest-point error's
lateral part. World frame, metres and radians throughout.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import casadi as ca
import numpy as np

from planner.beam.graph import beam_function, system_params
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
from planner.model.system import System
from planner.model.transforms import Array, plane_basis

SPOT_JACOBIAN_OUTPUTS = ["spot", "jacobian", "direction"]


@lru_cache(maxsize=16)
def spot_jacobian_function(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...]
) -> ca.Function:
    """Named ``servo_spot``: beam inputs (``q``, geometry, ``target``, non-zero ``normal``) ->
    ``spot`` (3, world m), ``jacobian`` (3 x nq, d spot / dq, m/rad) and ``direction`` (3,
    unit last ray)."""
    beam = beam_function(kinematics, surfaces)
    args = {name: ca.SX.sym(name, beam.sparsity_in(name)) for name in beam.name_in()}
    out = beam.call(args)
    spot = out["spot"]
    dirs = out["dirs"]
    outputs = {
        "spot": spot,
        "jacobian": ca.jacobian(spot, args["q"]),
        "direction": dirs[:, dirs.shape[1] - 1],
    }
    return ca.Function("servo_spot", args | outputs, list(args), SPOT_JACOBIAN_OUTPUTS)


def surface_axes(normal: Array) -> Array:
    """The in-plane axes ``[e1, e2]`` (3 x 2) of a surface with unit ``normal`` (world)."""
    return plane_basis(normal)[:, 1:]


class SpotJacobian(NamedTuple):
    """The model's spot at one configuration on one target plane (world frame)."""

    spot: Array  # (3,) m, on the plane
    jacobian: Array  # (3, nq) d spot / dq, m/rad
    direction: Array  # (3,) unit last ray
    axes: Array  # (3, 2) in-plane axes [e1, e2] of the plane's normal

    @property
    def plane_jacobian(self) -> Array:
        """d (spot in plane coordinates) / dq (2 x nq, m/rad)."""
        return self.axes.T @ self.jacobian


class SpotModel:
    """The calibrated model's spot and its Jacobian for one system."""

    def __init__(self, system: System) -> None:
        self.system = system
        self.function = spot_jacobian_function(system.kinematics, system.surfaces)
        self.params = system_params(system)

    def evaluate(self, q: Array, target: Array, normal: Array) -> SpotJacobian:
        """The spot on the plane through ``target`` (world, m) with unit ``normal`` at
        stacked joints ``q`` (rad), with its Jacobian. ``normal`` must be non-zero."""
        n = np.asarray(normal, dtype=float)
        if not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-9:
            raise ValueError(f"the servo's plane needs a finite non-zero normal, got {n}")
        n = n / np.linalg.norm(n)
        out = self.function(q=np.asarray(q, dtype=float), **self.params, target=target, normal=n)
        return SpotJacobian(
            spot=np.asarray(out["spot"], dtype=float).ravel(),
            jacobian=np.asarray(out["jacobian"], dtype=float),
            direction=np.asarray(out["direction"], dtype=float).ravel(),
            axes=surface_axes(n),
        )

    def plane_normal(self, q: Array, target: Array, normal: Array | None) -> Array:
        """The normal of the servo's plane: the target's unit ``normal``, or without one minus
        the model's last ray at ``q`` (the plane across the arriving beam)."""
        if normal is not None:
            n = np.asarray(normal, dtype=float)
            return n / np.linalg.norm(n)
        out = self.function(q=np.asarray(q, dtype=float), **self.params, target=target,
                            normal=np.array([0.0, 0.0, 1.0]))  # fmt: skip
        return -np.asarray(out["direction"], dtype=float).ravel()
