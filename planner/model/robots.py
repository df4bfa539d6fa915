"""Robot models by name: kinematics, default joint limits and collision shapes.

A scenario robot names its model (``model: ur5e``, the default) or gives a URDF
(``urdf: arm.urdf``); :func:`robot_model` turns either into a :class:`RobotModel`. A new arm
is one :func:`register_model` call with a factory; a URDF needs no registration and uses its
own ``<limit>`` values (acceleration and jerk, which URDF lacks, take the defaults).

Example::

    register_model("ur5e_lab", lambda: urdf_model("/lab/ur5e_calibrated.urdf", "ur5e_lab",
                                                  collision=UR5E_SHAPES))
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from planner.errors import InputError
from planner.model.collision import CollisionShapes
from planner.model.kinematics import RobotKinematics
from planner.model.limits import Limits
from planner.model.ur5e import UR5E_SHAPES

DEFAULT_MODEL = "ur5e"


@dataclass(frozen=True)
class RobotModel:
    """One arm type: ``kinematics`` (``base_T_flange`` and IK helpers), ``limits`` (the
    defaults a scenario's ``limits:`` overrides key by key; rad, rad/s, rad/s^2, rad/s^3) and
    ``collision`` (its link shapes for the safety checks; None: none known, so collision
    checks refuse it)."""

    name: str
    kinematics: RobotKinematics
    limits: Limits
    collision: CollisionShapes | None = None

    @property
    def nq(self) -> int:
        return self.kinematics.nq


ModelFactory = Callable[[], RobotModel]
_FACTORIES: dict[str, ModelFactory] = {}
_BUILT: dict[str, RobotModel] = {}


def register_model(name: str, factory: ModelFactory, *, replace: bool = False) -> None:
    """Make ``model: <name>`` available to scenarios.

    Args:
        name: the scenario's ``model`` value (not ending in ``.urdf``).
        factory: builds the :class:`RobotModel` once, on first use (e.g. :func:`urdf_model`).
        replace: allow replacing a registered name (else ``ValueError``).
    """
    if not name or name.endswith(".urdf"):
        raise ValueError(f"not a model name: {name!r}")
    if name in _FACTORIES and not replace:
        raise ValueError(f"robot model {name!r} is already registered")
    _FACTORIES[name] = factory
    _BUILT.pop(name, None)


def unregister_model(name: str) -> None:
    """Forget a registered model (e.g. one a test registered)."""
    _FACTORIES.pop(name, None)
    _BUILT.pop(name, None)


def known_models() -> tuple[str, ...]:
    """Names :func:`robot_model` accepts, sorted."""
    return tuple(sorted(_FACTORIES))


def urdf_model(
    path: str | Path, name: str | None = None, *, collision: CollisionShapes | None = None
) -> RobotModel:
    """A model from a URDF file: its kinematics and its own limits (``InputError`` if the
    file is missing or not a serial arm)."""
    kin = RobotKinematics.from_urdf(path, name=name)
    return RobotModel(kin.name, kin, kin.default_limits(), collision)


def robot_model(name_or_urdf: str | Path) -> RobotModel:
    """A robot model by name or URDF file.

    Args:
        name_or_urdf: a registered name (``"ur5e"``), or a URDF file (a ``Path`` or a string
            ending in ``.urdf``; cached by absolute path).

    Returns:
        The :class:`RobotModel` (built once). Raises :class:`InputError` for an unknown name
        (listing the known ones) or an unreadable URDF.
    """
    if isinstance(name_or_urdf, Path) or name_or_urdf.endswith(".urdf"):
        key = str(Path(name_or_urdf).expanduser().resolve())
        if key not in _BUILT:
            _BUILT[key] = urdf_model(key)
        return _BUILT[key]
    name = name_or_urdf
    if name not in _BUILT:
        factory = _FACTORIES.get(name)
        if factory is None:
            raise InputError(f"unknown robot model {name!r} (known: {', '.join(known_models())})")
        model = factory()
        if model.limits.lower.shape != (model.nq,):
            raise InputError(f"robot model {name!r}: limits for {model.limits.lower.shape} "
                             f"joints, kinematics has {model.nq}")  # fmt: skip
        _BUILT[name] = model
    return _BUILT[name]


def collision_shapes(name: str) -> CollisionShapes | None:
    """The link shapes of the registered model ``name`` (a robot's ``kinematics.name``);
    None when no model of that name is registered or it has none."""
    return robot_model(name).collision if name in _FACTORIES else None


def _ur5e() -> RobotModel:
    kin = RobotKinematics.ur5e()
    return RobotModel(DEFAULT_MODEL, kin, kin.default_limits(), UR5E_SHAPES)


register_model(DEFAULT_MODEL, _ur5e)
