"""The checker's twin of the robot-model registry (:mod:`planner.model.robots`): per arm
model, the checker's OWN forward kinematics and safety shapes, written apart from the
planner's (no Pinocchio, no CasADi) so that a plan is re-checked by independent code.

A new arm is one :func:`register_checker_arm` beside its :func:`planner.model.robots.
register_model`; a model without a twin is still planned, but ``beamrelay check`` says it
cannot re-check it (never with another arm's kinematics). A URDF robot needs no twin: the
checker reads the URDF itself (:mod:`planner.verify.urdf`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from planner.model.transforms import Array
from planner.verify.numpy_beam import ur5e_dh_fk
from planner.verify.safety_shapes import Shape, arm_shapes

#: ``(world_T_base, Q (M x nq) rad, flange_T_mirror, mirror size (2,) m)`` -> the arm's
#: capsules and boxes at each row, world frame
ShapesOf = Callable[[Array, Array, Array, Array], list[Shape]]


@dataclass(frozen=True)
class CheckerArm:
    """One arm model as the checker knows it: ``nq`` joints, ``fk`` the batched
    ``base_T_flange`` (M x nq rad -> M x 4 x 4; (nq,) -> 4 x 4), ``shapes`` its collision
    geometry for the safety re-check (None: its safety is reported unchecked)."""

    nq: int
    fk: Callable[[Array], Array]
    shapes: ShapesOf | None = None


_ARMS: dict[str, CheckerArm] = {"ur5e": CheckerArm(6, ur5e_dh_fk, arm_shapes)}
DEFAULT_MODEL = "ur5e"  # a scenario robot without model or urdf (SPEC section 4)


def register_checker_arm(name: str, arm: CheckerArm, *, replace: bool = False) -> None:
    """Make the checker able to re-check ``model: <name>`` robots (ValueError if the name
    is taken and ``replace`` is false)."""
    if name in _ARMS and not replace:
        raise ValueError(f"checker arm {name!r} is already registered")
    _ARMS[name] = arm


def unregister_checker_arm(name: str) -> None:
    """Forget a registered twin (e.g. one a test registered); the UR5e stays."""
    if name != DEFAULT_MODEL:
        _ARMS.pop(name, None)


def checker_arm(model: str | None) -> CheckerArm | None:
    """The twin of ``model`` (None: the default UR5e), or None when the checker has none."""
    return _ARMS.get(model or DEFAULT_MODEL)
