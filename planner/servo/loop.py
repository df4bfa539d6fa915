"""The spot servo loop: measure, correct, measure again, until within tolerance.

:func:`servo` starts where the open-loop plan put the arm(s) (``q0``), measures the spot
(:class:`~planner.servo.measure.Measure`: move, grab ``first_frames`` frames, average: the
open-loop error is large, one frame's noise does not matter for the first correction), and while
the measured error ``|spot - target|`` (m, 3D, world) is above the tolerance applies the
:class:`~planner.servo.step.Corrector`'s step and measures again (``frames`` frames). It stops
as

- ``converged``: the measured error is within the tolerance, with ``confidence`` standard
  errors of the measurement to spare (:func:`within_tolerance`); a measurement within the
  tolerance but not with confidence is confirmed once at the same joints with
  ``confirm_frames`` more frames, merged with it (its entry in ``errors`` is the merged one);
- ``not_improving``: a step reduced the best error so far by less than ``min_improvement``
  (a model too far off), unless the error is already within ``noise_floor`` times the
  tolerance: there camera noise decides, and the loop keeps correcting from the latest
  measurement (up to ``max_iterations``);
- ``not_seen``: the camera saw no spot (at the start, or after a step);
- ``refused``: the next step would break a joint limit, the beam chain or a safety rule
  (the result's ``failure`` says which, with its evidence);
- ``max_iterations``; ``aborted``: ``should_stop()`` said so, checked before and after
  every measurement (a stop request; nothing more is commanded).

When the loop stops as not improving or not seen and the last commanded configuration is
not the best measured one, the arm(s) go back to the best one and its spot is measured
again; the result's ``q`` is always where the arms are left and ``error_after`` was
measured there.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.model.status import Failure, ServoStatus
from planner.model.transforms import Array
from planner.servo.measure import Measure, SpotMeasurement, merge
from planner.servo.step import Corrector, ServoSettings


@dataclass(frozen=True)
class ServoResult:
    """One target's servo run. ``q``: stacked joints (rad) the arms were left at;
    ``iterations``: correction steps commanded; ``frames``: camera frames grabbed; ``time``
    (s) of the run; ``error_before`` / ``error_after`` (m): measured error at ``q0`` and at
    ``q`` (NaN when not seen); ``errors``: every measurement's error in order (NaN = not
    seen); ``spot``: the last measured spot at ``q`` (world, m) or None; ``failure``: why a
    step was refused."""

    status: ServoStatus
    q: Array
    iterations: int
    frames: int
    time: float
    error_before: float
    error_after: float
    errors: tuple[float, ...]
    spot: Array | None
    failure: Failure | None = None

    @property
    def converged(self) -> bool:
        return self.status is ServoStatus.CONVERGED

    def to_json(self) -> dict[str, Any]:
        """JSON-ready figures (m, s; NaN as null)."""

        def num(x: float) -> float | None:
            return None if not np.isfinite(x) else float(x)

        return {
            "status": str(self.status),
            "iterations": self.iterations,
            "frames": self.frames,
            "time": float(self.time),
            "measured_error_before": num(self.error_before),
            "measured_error_after": num(self.error_after),
            "errors": [num(e) for e in self.errors],
            "measured_spot": None if self.spot is None else [float(x) for x in self.spot],
            "reason": None if self.failure is None else str(self.failure.reason),
            "detail": None if self.failure is None else self.failure.detail,
        }


class _Run:
    """Book-keeping of one run: frames, errors, the best measurement so far."""

    def __init__(self, measure: Measure, target: Array, frames: int) -> None:
        self.measure, self.target, self.n = measure, target, frames
        self.frames = 0
        self.errors: list[float] = []

    def take(self, q: Array, n: int | None = None) -> SpotMeasurement | None:
        n = self.n if n is None else n
        m = self.measure(q, n)
        self.frames += n if m is None else m.frames
        self.errors.append(
            np.nan if m is None else float(np.linalg.norm(m.spot_world - self.target))
        )
        return m


def within_tolerance(err: float, m: SpotMeasurement, s: ServoSettings) -> bool:
    """Whether measured error ``err`` (m) of measurement ``m`` is within the tolerance with
    ``s.confidence`` standard errors (spread / sqrt(frames seen)) to spare."""
    standard_error = m.spread / np.sqrt(max(m.seen, 1))
    return bool(err + s.confidence * standard_error <= s.tolerance)


# long: the loop's stops (converged, confirmed, not improving, not seen, refused, aborted, back to best) read as one loop against its docstring
def servo(
    measure: Measure,
    q0: Array,
    target: Array,
    normal: Array | None,
    corrector: Corrector,
    settings: ServoSettings | None = None,
    *,
    should_stop: Callable[[], bool] | None = None,
) -> ServoResult:
    """Servo the spot onto ``target`` (world, m; unit surface ``normal`` or None) from stacked
    joints ``q0`` (rad), where the arm(s) already are. ``settings`` default to the
    corrector's. See the module docstring for the statuses."""
    s = settings or corrector.settings
    stop = should_stop or (lambda: False)
    t0 = time.perf_counter()
    target = np.asarray(target, dtype=float)
    q0 = np.asarray(q0, dtype=float)
    run = _Run(measure, target, s.frames)

    def result(status: ServoStatus, q: Array, m: SpotMeasurement | None, it: int,
               failure: Failure | None = None) -> ServoResult:  # fmt: skip
        err = run.errors[-1] if m is not None else np.nan
        return ServoResult(status, q, it, run.frames, time.perf_counter() - t0,
                           run.errors[0] if run.errors else np.nan, err, tuple(run.errors),
                           None if m is None else m.spot_world, failure)  # fmt: skip

    if stop():
        return result(ServoStatus.ABORTED, q0, None, 0)
    m = run.take(q0, s.first_frames)
    if stop():
        return result(ServoStatus.ABORTED, q0, None, 0)
    if m is None:
        return result(ServoStatus.NOT_SEEN, q0, None, 0)
    plane_normal = corrector.model.plane_normal(q0, target, normal)
    best_q, best_m, best_err = q0, m, run.errors[-1]
    cur_q, cur_m, cur_err = q0, m, best_err
    it = 0
    confirmed: Array | None = None  # the joints whose measurement was confirmed
    while True:
        if within_tolerance(cur_err, cur_m, s):
            return result(ServoStatus.CONVERGED, cur_q, cur_m, it)
        if cur_err <= s.tolerance and confirmed is not cur_q:
            confirmed = cur_q
            extra = run.take(cur_q, s.confirm_frames)
            if stop():
                return result(ServoStatus.ABORTED, cur_q, None, it)
            if extra is not None:
                cur_m = merge(cur_m, extra)
                cur_err = run.errors[-1] = float(np.linalg.norm(cur_m.spot_world - target))
                if best_q is cur_q:
                    best_m, best_err = cur_m, cur_err
            else:  # not seen now: the merged entry is the one measurement's
                run.errors[-1] = cur_err
            continue
        if it >= s.max_iterations:
            return result(ServoStatus.MAX_ITERATIONS, cur_q, cur_m, it)
        step = corrector.step(cur_q, target, normal, plane_normal, cur_m.spot_world - target)
        if step.failure is not None:
            return result(ServoStatus.REFUSED, cur_q, cur_m, it, step.failure)
        if stop():
            return result(ServoStatus.ABORTED, cur_q, None, it)
        it += 1
        m_new = run.take(step.q)
        if stop():
            return result(ServoStatus.ABORTED, step.q, None, it)
        err = run.errors[-1]
        if m_new is not None:
            improved = err <= (1.0 - s.min_improvement) * best_err
            near_floor = min(err, best_err) <= s.noise_floor * s.tolerance
            if err < best_err:
                best_q, best_m, best_err = step.q, m_new, err
            if improved or near_floor or err <= s.tolerance:
                cur_q, cur_m, cur_err = step.q, m_new, err
                continue
        status = ServoStatus.NOT_SEEN if m_new is None else ServoStatus.NOT_IMPROVING
        if best_q is not step.q:  # worse or lost: back to the best configuration
            if stop():
                return result(ServoStatus.ABORTED, step.q, None, it)
            back = run.take(best_q)
            return result(status, best_q, back, it)
        return result(status, best_q, best_m, it)
