"""One closed-loop correction: a measured spot error -> a bounded, checked joint step.

The error ``e = measured spot - target`` (world, m) is expressed in the servo plane's axes
(:mod:`planner.servo.jacobian`) and the damped minimum-norm step

    dq = -gain * Jp^T (Jp Jp^T + damping^2 I)^-1 (A^T e),    Jp = A^T d spot / dq

moves the *model's* spot by minus that error (the model geometry's error is what is
corrected: the step is computed in the calibrated model, the camera measures the truth).
A step whose largest joint change exceeds ``max_step`` (rad) is scaled down to it. The new
configuration must keep every joint within its position limits, the model's beam a valid
chain on the target (:mod:`planner.model.validity`) and, with safety rules, pass them
(:class:`planner.safety.Safety`); a step that breaks a rule is refused with the reason and
its evidence. The safety rules see the beam ending at the spot the step is expected to
reach, ``measured spot + J dq`` (world, m; J = d spot / dq of the model at ``q``), not the
model's spot: the model is off by the calibration error, the measurement is not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from planner.beam.trace import trace_beam
from planner.model.status import Failure, Reason
from planner.model.system import System
from planner.model.transforms import Array
from planner.model.validity import ahead_ok, front_ok, roi_ok
from planner.safety.model import Safety
from planner.servo.jacobian import SpotModel
from schemas.defaults import (
    SERVO_FIRST_FRAMES,
    SERVO_FRAMES,
    SERVO_MAX_ITERATIONS,
    SERVO_MAX_STEP_RAD,
    SERVO_TOLERANCE_M,
)


@dataclass(frozen=True)
class ServoSettings:
    """``tolerance`` (m): measured error that counts as converged; ``max_iterations``:
    correction steps at most; ``frames``: camera frames per measurement, ``first_frames`` for
    the first (open-loop) one; ``max_step`` (rad):
    largest joint change per step; ``damping`` (m/rad) of the least squares; ``gain`` (1 =
    the full correction); ``min_improvement``: fraction by which a step must reduce the best
    measured error so far, else the loop stops as not improving, unless the error is within
    ``noise_floor`` times the tolerance (there the camera's noise decides); ``confidence``:
    how many standard errors of the measurement (its frames' spread / sqrt(frames seen))
    must fit inside the tolerance on top of the measured error for it to count as converged
    (the treatment follows: a 0.25 mm measurement of 0.09 mm standard error is not within
    0.3 mm with confidence); ``confirm_frames``: frames of the one confirming measurement
    taken where a measurement is within the tolerance but not yet with confidence (merged
    with it)."""

    tolerance: float = SERVO_TOLERANCE_M
    max_iterations: int = SERVO_MAX_ITERATIONS
    frames: int = SERVO_FRAMES
    first_frames: int = SERVO_FIRST_FRAMES
    max_step: float = SERVO_MAX_STEP_RAD
    damping: float = 1e-3
    gain: float = 1.0
    min_improvement: float = 0.1
    noise_floor: float = 2.0
    confidence: float = 2.0
    confirm_frames: int = 3 * SERVO_FRAMES

    def __post_init__(self) -> None:
        positive = {"tolerance": self.tolerance, "max_step": self.max_step, "gain": self.gain}
        for name, v in positive.items():
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"servo {name} must be finite and > 0, got {v}")
        if not (math.isfinite(self.damping) and self.damping >= 0):
            raise ValueError(f"servo damping must be finite and >= 0 m/rad, got {self.damping}")
        if not (math.isfinite(self.noise_floor) and self.noise_floor >= 1.0):
            raise ValueError(
                f"servo noise_floor must be >= 1 (x tolerance), got {self.noise_floor}"
            )
        if not (math.isfinite(self.confidence) and self.confidence >= 0):
            raise ValueError(f"servo confidence must be finite and >= 0, got {self.confidence}")
        if not (0.0 <= self.min_improvement < 1.0):
            raise ValueError(f"servo min_improvement must be in [0, 1), got {self.min_improvement}")
        if self.max_iterations < 0 or min(self.frames, self.first_frames, self.confirm_frames) < 1:
            raise ValueError(f"servo needs max_iterations >= 0 and frames, first_frames >= 1, "
                             f"got {self.max_iterations}, {self.frames}, {self.first_frames}"
                             f" (confirm_frames {self.confirm_frames})")  # fmt: skip


class Step(NamedTuple):
    """A correction step: ``q`` the new stacked joints (rad), ``dq`` the step, ``failure``
    None when accepted, else why it was refused (``q`` is then the unchanged start),
    ``error_plane`` the measured error in the plane's axes (2, m)."""

    q: Array
    dq: Array
    failure: Failure | None
    error_plane: Array

    @property
    def ok(self) -> bool:
        return self.failure is None


def limit_failure(system: System, q: Array) -> Failure | None:
    """The worst joint outside its position limits at stacked ``q`` (rad), or None."""
    over, under = q - system.upper, system.lower - q
    worst = int(np.argmax(np.maximum(over, under)))
    if max(over[worst], under[worst]) <= 0.0:
        return None
    names = [f"{r.name} {j}" for r in system.robots for j in r.joint_names]
    side, limit = ("upper", system.upper) if over[worst] > 0 else ("lower", system.lower)
    return Failure(Reason.JOINT_LIMITS, f"{names[worst]} at {q[worst]:.4f} rad beyond its "
                   f"{side} limit {limit[worst]:.4f} rad")  # fmt: skip


class Corrector:
    """Correction steps in one system's calibrated model, under its safety rules (optional)."""

    def __init__(
        self, system: System, safety: Safety | None = None, settings: ServoSettings | None = None
    ) -> None:
        self.system = system
        self.safety = safety
        self.settings = settings or ServoSettings()
        self.model = SpotModel(system)

    def check(
        self, q: Array, target: Array, normal: Array | None, spot: Array | None = None
    ) -> Failure | None:
        """Why stacked joints ``q`` (rad) may not be commanded for ``target`` (world, m; its
        unit ``normal`` or None): joint limits, the model's beam chain, the safety rules,
        these with the beam ending at ``spot`` (world, m: the expected real spot) when given,
        else at the model's spot."""
        if not np.all(np.isfinite(q)):
            return Failure(Reason.SOLVER_FAILED, "non-finite joint step")
        bad = limit_failure(self.system, q)
        if bad is not None:
            return bad
        tr = trace_beam(self.system, q, target, normal)
        if not front_ok(tr.front).all() or not ahead_ok(tr.target_ahead):
            return Failure(Reason.BACK_FACE, f"front {tr.front.min():.3g}, target ahead "
                           f"{tr.target_ahead:.4f} m")  # fmt: skip
        if not roi_ok(tr.roi).all():
            return Failure(Reason.OUTSIDE_ROI, f"beam {-1e3 * tr.roi.min():.2f} mm outside "
                           "a mirror's region of interest")  # fmt: skip
        if not ahead_ok(tr.ahead).all():
            return Failure(Reason.UNREACHABLE, f"a mirror behind the beam ({tr.ahead.min():.4f} m)")
        if self.safety is not None:
            end = tr.spot if spot is None else np.asarray(spot, dtype=float)
            P = np.vstack([self.system.world_T_laser[:3, 3], tr.hits, end])
            v = self.safety.config(q, P)
            if v is not None:
                return Failure(Reason(v.reason), v.text)
        return None

    def step(
        self, q: Array, target: Array, normal: Array | None, plane_normal: Array, error: Array
    ) -> Step:
        """The correction of a measured ``error`` (spot - target, world, m) at stacked joints
        ``q`` (rad) for ``target`` (world, m) with its unit ``normal`` (or None); the error is
        taken in the plane with ``plane_normal`` (:meth:`SpotModel.plane_normal`). The new
        joints are checked with the beam ending at ``target + error + J dq``."""
        s = self.settings
        q = np.asarray(q, dtype=float)
        sj = self.model.evaluate(q, target, plane_normal)
        e2 = sj.axes.T @ np.asarray(error, dtype=float)
        Jp = sj.plane_jacobian
        A = Jp @ Jp.T + s.damping**2 * np.eye(2)
        dq = -s.gain * Jp.T @ np.linalg.solve(A, e2)
        big = float(np.max(np.abs(dq)))
        if big > s.max_step:
            dq *= s.max_step / big
        q_new = q + dq
        target = np.asarray(target, dtype=float)
        expected = target + np.asarray(error, dtype=float) + sj.jacobian @ dq  # measured + J dq
        failure = self.check(q_new, target, normal, expected)
        if failure is not None:
            return Step(q, dq, failure, e2)
        return Step(q_new, dq, None, e2)
