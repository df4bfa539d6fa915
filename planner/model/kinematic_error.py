"""Kinematic error of a real UR5e: the true arm's DH parameters about the nominal ones.

A real arm is not its nominal model: every joint's zero, every link length and every twist
differs a little (assembly, part tolerances). UR measures them per arm at the factory and
the controller uses them; a planner on the published nominal DH does not. This module makes
such a true arm for the simulation (the planner keeps the nominal model).

Error model: the UR controller's own parametrisation (its ``calibration.conf``:
``delta_theta``, ``delta_a``, ``delta_d``, ``delta_alpha`` per joint, read by
``ur_calibration``) plus a rotation ``beta`` about y (Hayati), which the parallel joints
2-4 need for a tilt that plain DH cannot express. Link i of the true arm is

    Rz(q_i + dtheta_i) Tz(d_i + dd_i) Tx(a_i + da_i) Rx(alpha_i + dalpha_i) Ry(dbeta_i)

(the nominal link with every delta 0; ``planner.model.kinematics.UR5E_DH``). Joints in
rad, lengths in m.

Levels (:class:`KinematicSpread`, Gaussian per parameter, drawn per trial):

- :data:`FACTORY`: a factory-calibrated UR5e whose factory calibration the planner does not
  load (it plans on the nominal DH): the true arm differs from nominal by what UR's factory
  calibration of a UR5e measured. Spreads: the RMS deviations of a published UR5e factory
  calibration (:data:`UR5E_FACTORY_SAMPLE`) from the nominal kinematics.
- :data:`UNCALIBRATED`: a larger, older-generation deviation: the RMS of the published
  factory calibration of a UR10 CB3 (:data:`CB3_SAMPLE`). An upper-end option, see there.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from planner.model.kinematics import UR5E_DH, RobotKinematics
from planner.model.transforms import Array, make_T, rpy_to_matrix

if TYPE_CHECKING:
    from planner.model.system import Robot

#: Source of :data:`FACTORY`: the deviations from the nominal UR5e kinematics
#: (``ur_description`` ``config/ur5e/default_kinematics.yaml``) of one UR5e's factory
#: calibration as extracted by ``ur_calibration`` (kinematics hash
#: ``calib_14698139022496758595``, published in a public GitHub repository), per joint
#: origin: lengths (m: shoulder z, upper-arm x, forearm x, wrist 1 x/y/z, wrist 2 x/y/z,
#: wrist 3 x/y/z; the entries the calibration left free), axis tilts (rad: roll/pitch of
#: upper arm, forearm, wrist 1, wrist 2, wrist 3) and joint-zero yaws (rad).
UR5E_FACTORY_SAMPLE = {
    "length": (
        2.122e-4,
        1.820e-4,
        -1.703e-4,
        -4.466e-4,
        -4.030e-4,
        -1.937e-4,
        -7.07e-6,
        -3.2e-7,
        9.64e-5,
        1.37e-5,
        -1.52e-5,
        9.52e-5,
    ),
    "angle": (5.185e-4, 1.4443e-3, -4.261e-4, 3.0279e-3, -1.1857e-3, 3.2e-6, 9.561e-4),
    "zero": (5.7e-8, 1.12e-6, 4.64e-6, -2.57e-6, 1.30e-6, -1.43e-7),
}
#: Source of :data:`UNCALIBRATED`: the ``calibration.conf`` deltas of a real UR10 CB3 in
#: ``ur_calibration``'s test (Universal_Robots_ROS_Driver, ``ur_calibration/test/
#: calibration_test.cpp``, test ``calibration``): delta_a of every joint, delta_d and
#: delta_theta of joints 1, 5, 6 (those of the parallel joints 2-4 run to metres and cancel
#: each other, a redundancy of the parametrisation, not an error), delta_alpha of every
#: joint. Its tilts of the parallel joints (7 and 13 mrad) belong with those large d's, so
#: taken alone they overstate the arm's error: an upper-end level.
CB3_SAMPLE = {
    "length": (
        4.631e-5,
        -1.2568e-4,
        1.8622e-3,
        9.919e-5,
        4.22e-6,
        6.561e-4,
        -1.574e-5,
        1.907e-5,
    ),
    "angle": (2.120e-4, -7.2554e-3, -1.34832e-2, 1.3496e-3, -1.2631e-3),
    "zero": (-7.290e-5, 1.49e-7, 1.5515e-5),
}


def _rms(values: tuple[float, ...]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


@dataclass(frozen=True)
class KinematicSpread:
    """Standard deviations of the true arm's DH deltas: joint zeros (rad), lengths d and a
    (m), twists alpha and tilts beta (rad)."""

    name: str
    zero: float
    length: float
    angle: float

    @classmethod
    def from_sample(cls, name: str, sample: dict[str, tuple[float, ...]]) -> KinematicSpread:
        """The spread whose sigma per kind is the RMS of a published calibration's deviations."""
        return cls(name, _rms(sample["zero"]), _rms(sample["length"]), _rms(sample["angle"]))

    def describe(self) -> str:
        """One line: the sigmas in mm / mrad."""
        return (f"{self.name}: joint zeros {1e3 * self.zero:.3g} mrad, lengths "
                f"{1e3 * self.length:.3g} mm, twists/tilts {1e3 * self.angle:.3g} mrad (1 sigma)")  # fmt: skip

    def draw(self, rng: np.random.Generator, n: int = 6) -> DHError:
        """One true arm's deltas (Gaussian, independent per parameter)."""
        g = rng.standard_normal((5, n))
        return DHError(self.zero * g[0], self.length * g[1], self.length * g[2],
                       self.angle * g[3], self.angle * g[4])  # fmt: skip


FACTORY = KinematicSpread.from_sample("factory-calibrated UR5e", UR5E_FACTORY_SAMPLE)
UNCALIBRATED = KinematicSpread.from_sample("uncalibrated (CB3-generation)", CB3_SAMPLE)
LEVELS = {"none": None, "factory": FACTORY, "uncalibrated": UNCALIBRATED}
"""The ``--robot-error`` levels by name (none: the true arm is the nominal one)."""


@dataclass(frozen=True)
class DHError:
    """Deltas of the true arm about the nominal DH, per joint (arrays of 6): ``dtheta``
    (joint zero, rad), ``dd``, ``da`` (m), ``dalpha`` (rad), ``dbeta`` (rad, about y)."""

    dtheta: Array
    dd: Array
    da: Array
    dalpha: Array
    dbeta: Array


def link_T(i: int, err: DHError | None = None) -> Array:
    """Link ``i``'s fixed part (after the joint's rotation q_i) of the true arm:
    ``Rz(dtheta) Tz(d + dd) Tx(a + da) Rx(alpha + dalpha) Ry(dbeta)`` (nominal: no ``err``)."""
    d, a, alpha = UR5E_DH["d"][i], UR5E_DH["a"][i], UR5E_DH["alpha"][i]
    e = np.zeros(5) if err is None else [err.dtheta[i], err.dd[i], err.da[i], err.dalpha[i],
                                         err.dbeta[i]]  # fmt: skip
    R = rpy_to_matrix([alpha + e[3], 0.0, 0.0]) @ rpy_to_matrix([0.0, e[4], 0.0])
    return make_T(rpy_to_matrix([0.0, 0.0, e[0]])) @ make_T(R, [a + e[2], 0.0, d + e[1]])


def perturbed_ur5e(err: DHError, nominal: RobotKinematics | None = None) -> RobotKinematics:
    """The true arm: the nominal UR5e model with link i's placement replaced by
    :func:`link_T` (``i, err``). Keeps the nominal's name (its collision shapes apply) but no
    analytic IK (that is for the nominal geometry)."""
    nominal = RobotKinematics.ur5e() if nominal is None else nominal
    model = nominal.model.copy()
    n = model.nq
    for i in range(n - 1):  # link i places joint i + 2 (Pinocchio joint ids start at 1)
        model.jointPlacements[i + 2] = pin.SE3(link_T(i, err))
    flange = model.frames[nominal.flange_id]
    flange.placement = pin.SE3(link_T(n - 1, err))
    model.frames[nominal.flange_id] = flange
    return RobotKinematics(model, name=nominal.name, source=f"{nominal.source} + DH error")


def true_robot(robot: Robot, spread: KinematicSpread, rng: np.random.Generator) -> Robot:
    """``robot`` with a true arm's kinematics: a draw of ``spread`` from ``rng`` applied to its
    (nominal) kinematics by :func:`perturbed_ur5e`; everything else unchanged."""
    return replace(robot, kinematics=perturbed_ur5e(spread.draw(rng, robot.nq), robot.kinematics))
