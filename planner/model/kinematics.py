"""Robot kinematics: a Pinocchio model behind one small class, plus its CasADi twin.

The PyPI ``pin`` wheels ship no ``pinocchio.casadi``, so :meth:`RobotKinematics.casadi_fk`
rebuilds ``base_T_flange(q)`` symbolically from the model's joint placements and axes.
Frames: ``base`` is the UR controller base frame, ``flange`` = ``tool0``.
"""

from __future__ import annotations

import threading
from functools import cached_property
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin

from planner.errors import InputError
from planner.model.limits import Limits
from planner.model.transforms import Array, inv_T

UR5E_DH = {
    "d": (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
    "a": (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0),
    "alpha": (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0),
}

#: every Kinematics writes its one Pinocchio ``data`` and reads it back: threads (tracking's
#: frame solver and setpoint check, a Zenoh callback) take turns (not an instance attribute:
#: a System pickles)
_DATA_LOCK = threading.Lock()
_REVOLUTE_AXES = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0)}
_REVOLUTE_AXES |= {"JointModelRZ": (0.0, 0.0, 1.0)}
_PRISMATIC_AXES = {"JointModelPX": (1.0, 0.0, 0.0), "JointModelPY": (0.0, 1.0, 0.0)}
_PRISMATIC_AXES |= {"JointModelPZ": (0.0, 0.0, 1.0)}


def ur5e_urdf_path() -> Path:
    """The shipped UR5e URDF (standard DH, frames ``base`` and ``tool0``)."""
    return Path(str(resources.files("planner.data").joinpath("ur5e.urdf")))


def _se3(M: pin.SE3) -> Array:
    return np.asarray(M.homogeneous, dtype=float)


def _axis_rotation(axis: Array, q: ca.SX) -> ca.SX:
    """4x4 homogeneous rotation about a unit axis by angle q (Rodrigues), symbolic."""
    x, y, z = (float(a) for a in axis)
    c, s = ca.cos(q), ca.sin(q)
    C = 1 - c
    R = ca.vertcat(
        ca.horzcat(c + x * x * C, x * y * C - z * s, x * z * C + y * s, 0),
        ca.horzcat(y * x * C + z * s, c + y * y * C, y * z * C - x * s, 0),
        ca.horzcat(z * x * C - y * s, z * y * C + x * s, c + z * z * C, 0),
        ca.horzcat(0, 0, 0, 1),
    )
    return R


def _axis_translation(axis: Array, q: ca.SX) -> ca.SX:
    T = ca.SX.eye(4)
    for i in range(3):
        T[i, 3] = float(axis[i]) * q
    return T


class RobotKinematics:
    """Forward kinematics ``base_T_flange(q)`` of a serial arm, numeric and symbolic.

    Build with :meth:`ur5e` (the shipped nominal model, with analytic IK) or
    :meth:`from_urdf` (any serial URDF; e.g. a UR with factory calibration offsets); by name
    or URDF path through the registry :func:`planner.model.robots.robot_model`.
    """

    def __init__(
        self,
        model: pin.Model,
        *,
        name: str,
        source: str,
        flange_frame: str = "tool0",
        base_frame: str = "base",
        analytic: str | None = None,
    ) -> None:
        for frame in (flange_frame, base_frame):
            if not model.existFrame(frame):
                names = ", ".join(f.name for f in model.frames)
                raise InputError(
                    f"frame {frame!r} not in the robot model (frames: {names})", source
                )
        if model.nq != model.nv:
            raise InputError("only 1-dof revolute or prismatic joints are supported", source)
        self.model = model
        self.data = model.createData()
        self.name = name
        self.source = source
        self.flange_id = model.getFrameId(flange_frame)
        self.base_id = model.getFrameId(base_frame)
        self.analytic = analytic
        pin.framesForwardKinematics(model, self.data, pin.neutral(model))
        self._universe_T_base = _se3(self.data.oMf[self.base_id])
        self._base_T_universe = inv_T(self._universe_T_base)

    # construction -------------------------------------------------------------------------
    @classmethod
    def ur5e(cls) -> RobotKinematics:
        """The nominal UR5e (published standard DH values), with the closed-form IK of
        ``ur-analytic-ik``."""
        path = ur5e_urdf_path()
        return cls(
            pin.buildModelFromUrdf(str(path)), name="ur5e", source=str(path), analytic="ur5e"
        )

    @classmethod
    def from_urdf(
        cls,
        path: str | Path,
        *,
        flange_frame: str = "tool0",
        base_frame: str = "base",
        name: str | None = None,
    ) -> RobotKinematics:
        """Any serial arm from a URDF file; no analytic IK (IPOPT/Newton only). ``name``
        defaults to the file's stem."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"URDF file not found: {path}")
        try:
            model = pin.buildModelFromUrdf(str(path))
        except (RuntimeError, ValueError) as exc:
            raise InputError(f"cannot load URDF: {exc}", str(path)) from exc
        return cls(
            model,
            name=path.stem if name is None else name,
            source=str(path),
            flange_frame=flange_frame,
            base_frame=base_frame,
        )

    # properties ---------------------------------------------------------------------------
    @property
    def nq(self) -> int:
        return int(self.model.nq)

    @cached_property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(self.model.names[1:])

    @property
    def lower(self) -> Array:
        return np.asarray(self.model.lowerPositionLimit, dtype=float)

    @property
    def upper(self) -> Array:
        return np.asarray(self.model.upperPositionLimit, dtype=float)

    @property
    def velocity(self) -> Array:
        """Joint velocity limits of the model (rad/s; URDF ``<limit velocity>``)."""
        return np.asarray(self.model.velocityLimit, dtype=float)

    def default_limits(self) -> Limits:
        """The model's own joint limits: position and velocity from the URDF ``<limit>``
        tags, acceleration and jerk (which URDF lacks) the conservative defaults.

        A joint without usable URDF values (missing, non-finite, empty range) gets the
        default of :meth:`Limits.ur_default` for that entry.
        """
        default = Limits.ur_default(self.nq)
        lower, upper, velocity = self.lower.copy(), self.upper.copy(), self.velocity.copy()
        bad = ~(np.isfinite(lower) & np.isfinite(upper) & (lower < upper))
        lower[bad], upper[bad] = default.lower[bad], default.upper[bad]
        bad_v = ~(np.isfinite(velocity) & (velocity > 0))
        velocity[bad_v] = default.velocity[bad_v]
        return Limits(lower, upper, velocity, default.acceleration, default.jerk)

    @property
    def base_T_universe(self) -> Array:
        """The model's root (the URDF's root link, Pinocchio's universe) in the ``base`` frame."""
        return self._base_T_universe.copy()

    @property
    def has_analytic_ik(self) -> bool:
        return self.analytic is not None

    # numeric ------------------------------------------------------------------------------
    def fk(self, q: Array) -> Array:
        """``base_T_flange`` at joints ``q`` (Pinocchio)."""
        with _DATA_LOCK:  # one Pinocchio data: written, then read, by one thread at a time
            pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
            return self._base_T_universe @ _se3(self.data.oMf[self.flange_id])

    def jacobian(self, q: Array) -> Array:
        """6 x nq Jacobian of the flange, rows (v, w) in base-frame axes (LOCAL_WORLD_ALIGNED).

        ``v`` is the velocity of the flange origin, ``w`` its angular velocity.
        """
        q = np.asarray(q, dtype=float)
        with _DATA_LOCK:
            pin.computeJointJacobians(self.model, self.data, q)
            pin.updateFramePlacements(self.model, self.data)
            J = pin.getFrameJacobian(
                self.model, self.data, self.flange_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
            )
            R = self._base_T_universe[:3, :3]
            return np.vstack([R @ J[:3], R @ J[3:]])

    def joint_origins(self, q: Array) -> Array:
        """``base``-frame origins of every joint, then the flange ((nq + 1) x 3, metres)."""
        with _DATA_LOCK:
            pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
            pts = [_se3(self.data.oMi[j])[:, 3] for j in range(1, self.model.njoints)]
            pts.append(_se3(self.data.oMf[self.flange_id])[:, 3])
            return (np.array(pts) @ self._base_T_universe.T)[:, :3]

    def analytic_ik(self, base_T_flange: Array) -> list[Array]:
        """All closed-form IK branches (up to 8) for the nominal UR model; [] otherwise."""
        if self.analytic is None:
            return []
        import ur_analytic_ik

        solver = getattr(ur_analytic_ik, self.analytic)
        T = np.ascontiguousarray(base_T_flange, dtype=float)
        return [np.asarray(s, dtype=float) for s in solver.inverse_kinematics(T)]

    # symbolic -----------------------------------------------------------------------------
    def casadi_fk_expr(self, q: ca.SX) -> ca.SX:
        """Symbolic 4x4 ``base_T_flange`` of an SX vector ``q`` (nq x 1)."""
        model = self.model
        oMi: list[ca.SX] = [ca.SX.eye(4)]
        for j in range(1, model.njoints):
            jm = model.joints[j]
            kind = jm.shortname()
            qj = q[jm.idx_q]
            if kind in _REVOLUTE_AXES or kind.startswith("JointModelRevoluteUnaligned"):
                axis = np.array(_REVOLUTE_AXES.get(kind) or jm.extract().axis, dtype=float)
                motion = _axis_rotation(axis, qj)
            elif kind in _PRISMATIC_AXES or kind.startswith("JointModelPrismaticUnaligned"):
                axis = np.array(_PRISMATIC_AXES.get(kind) or jm.extract().axis, dtype=float)
                motion = _axis_translation(axis, qj)
            else:
                raise InputError(f"joint {model.names[j]!r} of type {kind} is not supported")
            placement = ca.SX(_se3(model.jointPlacements[j]))
            oMi.append(ca.mtimes([oMi[model.parents[j]], placement, motion]))
        frame = model.frames[self.flange_id]
        world_T_flange = ca.mtimes(oMi[frame.parentJoint], ca.SX(_se3(frame.placement)))
        return ca.mtimes(ca.SX(self._base_T_universe), world_T_flange)

    @cached_property
    def casadi_fk(self) -> ca.Function:
        """``base_T_flange = f(q)`` as a named CasADi function (built once)."""
        q = ca.SX.sym("q", self.nq)
        return ca.Function(
            f"{self.name}_base_T_flange",
            [q],
            [self.casadi_fk_expr(q)],
            ["q"],
            ["base_T_flange"],
        )
