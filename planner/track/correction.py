"""Camera-frame spot correction while tracking: the camera sees the target and the spot, so
the model's error drops out.

Pure (no bus, no threads, no clock: every call takes its times). A tracked target given in
the camera frame is mapped to the world through the *calibrated* camera pose; so is every
spot the camera sees. A calibration error (camera pose, laser, mirror mount) then shows as
the measured spot S (mapped) lying off where the planner's model puts the beam at the same
joints. :class:`SpotCorrection`, per camera spot (:meth:`~SpotCorrection.on_spot`):

1. takes the arm's joints at the spot's capture time ``t`` (linear between the measured
   joint states around it) and the tracked point then (linear between the stream's frames
   around it);
2. traces the model's beam at those joints onto the target plane (through the point aimed
   at then, with the frame's normal; without one, the point of the ray nearest it): the
   model's spot M;
3. the model's error at that place is ``S - M`` less its component along the beam (the
   depth of a spot is the surface's, not the aim's); its running estimate :attr:`bias` is
   the exponential mean of these (weight :attr:`gain` of the new one). The follower aims at
   :meth:`corrected` ``= target - bias``: the beam as the truth has it then lands on the
   target as the camera sees it;
4. the delivery error ``|S - P(t)|`` (spot to target, both mapped through the same camera
   pose, so equal to their distance as the camera measured them) is :attr:`error`.

:meth:`permits` is the treatment's condition: a delivery error within ``tolerance`` measured
no longer than ``fresh`` s ago (a stamp more than :data:`AHEAD` s in the future is a clock
to distrust), and with keep-out volumes a model error within the calibration part of their
padding (``max_bias``: the rules check the model's beam, which misses the true one by about
the bias; with ``spot_uncertainty: 0`` that allows none: recalibrate or declare it). A spot is not used (counted in
:attr:`dropped` by why) when its confidence is under ``min_confidence``, when joints or
frames do not cover its time, when the model has no valid beam there, or when its model
error is farther than ``radius`` from the estimate (another bright point: the first one is
allowed ``first_radius``, the calibration's error bound); such an implausible spot also
withdraws the last delivery error (no treatment until a plausible one), and after
:data:`RESTART_AFTER` of them in a row the estimate starts again from nothing.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planner.beam.trace import trace_beam
from planner.model.system import System
from planner.model.transforms import Array

#: s of joint states and target frames kept to look up a spot's capture time in
HISTORY = 1.0
#: s: a spot stamped this far after ``now`` still counts (clocks of one machine); more is a
#: clock to distrust
AHEAD = 0.01
#: implausible spots in a row after which the estimate starts again (its first spot was
#: another bright point, or the calibration changed): no treatment until it has
RESTART_AFTER = 5


@dataclass
class SpotCorrection:
    """One tracked target's correction (see the module docstring). ``world_T_camera(q)``:
    the calibrated camera pose at stacked joints ``q`` (the node turns the correction on for
    a fixed camera only)."""

    system: System
    world_T_camera: Callable[[Array], Array]
    tolerance: float = 1e-3  # m, delivery error within which treatment is permitted
    gain: float = 0.5  # weight of a new spot's model error in the estimate
    fresh: float = 0.2  # s, how old the last delivery error may be for treatment
    min_confidence: float = 0.3
    first_radius: float = 0.03  # m, the first model error's largest size
    radius: float = 0.005  # m, a later one's largest distance from the estimate
    max_bias: float | None = None
    """m: with keep-out volumes, the largest model error the treatment tolerates (the
    calibration part of their padding); None: no limit"""
    bias: Array = field(default_factory=lambda: np.zeros(3))
    dropped: Counter[str] = field(default_factory=Counter)
    withheld: Counter[str] = field(default_factory=Counter)
    """setpoints whose treatment :meth:`permits` refused, by why"""

    def __post_init__(self) -> None:
        self._joints: deque[tuple[float, Array]] = deque()
        self._frames: deque[tuple[float, Array, Array | None]] = deque()
        self.used = 0  # spots that updated the estimate since it (re)started
        self.used_total = 0  # spots that updated an estimate
        self.restarts = 0  # estimates started again after implausible spots in a row
        self._implausible = 0  # implausible spots in a row
        # (m, s): the last measured delivery error and its capture time, or None; one tuple,
        # replaced whole, so the setpoint thread reads it without a lock
        self.last: tuple[float, float] | None = None
        self.errors: list[float] = []  # every measured delivery error (m), in order

    # --- inputs ----------------------------------------------------------------------------
    def on_joints(self, t: float, q: Array) -> None:
        """Measured stacked joints (rad) at ``t`` (s)."""
        _push(self._joints, (float(t), np.asarray(q, dtype=float)))

    def on_target(self, t: float, point: Array, normal: Array | None) -> None:
        """The tracked point (world, m, through the calibrated camera pose) captured at ``t``."""
        n = None if normal is None else np.asarray(normal, dtype=float)
        _push(self._frames, (float(t), np.asarray(point, dtype=float), n))

    def corrected(self, point: Array) -> Array:
        """Where to aim (world, m) for the spot to land on ``point`` as the camera sees it."""
        return np.asarray(point, dtype=float) - self.bias

    def on_spot(self, t: float, p_camera: Array | None, confidence: float) -> str:
        """A camera spot (optical frame, m; None: none seen) captured at ``t`` (s): ``used``,
        or why it was not (also counted in :attr:`dropped`)."""
        why = self._use(t, p_camera, confidence)
        if why != "used":
            self.dropped[why] += 1
        return why

    @property
    def error(self) -> float | None:
        """m: the last measured delivery error (None: none since the start or a bad spot)."""
        last = self.last
        return None if last is None else last[0]

    def permits(self, now: float) -> bool:
        """Whether the treatment may be on at ``now`` (s): the last delivery error is within
        :attr:`tolerance`, was measured at most :attr:`fresh` s before ``now`` (and at most
        :data:`AHEAD` s after: a stamp from the future is a clock to distrust), and the model
        error is within :attr:`max_bias`. Reads two attributes that are only ever replaced
        whole, never changed in place: safe from any thread without a lock. A refusal is
        counted by its reason in :attr:`withheld` (one caller: the setpoint thread)."""
        why = self._refusal(now)
        if why is not None:
            self.withheld[why] += 1
        return why is None

    def _refusal(self, now: float) -> str | None:
        last, bias = self.last, self.bias
        if last is None:
            return "no_measurement"
        if self.over_limit(bias):
            return "bias_over_limit"
        if last[0] > self.tolerance:
            return "over_tolerance"
        age = now - last[1]
        return "ahead" if age < -AHEAD else "stale" if age > self.fresh else None

    def over_limit(self, bias: Array | None = None) -> bool:
        """Whether the model error (default the estimate) exceeds :attr:`max_bias`."""
        b = self.bias if bias is None else bias
        return self.max_bias is not None and float(np.linalg.norm(b)) > self.max_bias

    # --- the estimate ----------------------------------------------------------------------
    def _use(self, t: float, p_camera: Array | None, confidence: float) -> str:
        if p_camera is None:
            return "not_seen"
        if confidence < self.min_confidence:
            return "low_confidence"
        q = _at(self._joints, t)
        frame = _frame_at(self._frames, t)
        if q is None or frame is None:
            return "no_joints" if q is None else "no_frame"
        target, normal = frame
        T = self.world_T_camera(q)
        spot = T[:3, :3] @ np.asarray(p_camera, dtype=float) + T[:3, 3]
        tr = trace_beam(self.system, q, self.corrected(target), normal)
        v = tr.dirs[-1] / np.linalg.norm(tr.dirs[-1])
        err = spot - tr.spot
        err = err - (err @ v) * v
        if not tr.valid or not np.all(np.isfinite(err)):
            return "model_invalid"  # no model spot to compare with (off the mirror, NaN)
        first = self.used == 0
        off = float(np.linalg.norm(err if first else err - self.bias))
        if not off <= (self.first_radius if first else self.radius):
            self.last = None  # the camera contradicts the estimate: no treatment on it
            self._implausible += 1
            if self._implausible >= RESTART_AFTER:
                self._restart()
            return "implausible"
        self._implausible = 0
        self.bias = err if first else self.bias + self.gain * (err - self.bias)
        self.used += 1
        self.used_total += 1
        error = float(np.linalg.norm(spot - target))
        self.last = (error, float(t))
        self.errors.append(error)
        return "used"

    def _restart(self) -> None:
        self.bias, self.used, self._implausible, self.last = np.zeros(3), 0, 0, None
        self.restarts += 1

    def figures(self) -> dict[str, object]:
        """For the tracking summary: spots used and dropped, the estimate (mm) and its limit,
        the setpoints whose treatment was withheld by why, the delivery errors measured (mm:
        first, median of the last half, last)."""
        e = np.asarray(self.errors) * 1e3
        out: dict[str, object] = {"frame": "camera", "spots_used": self.used_total,
                                  "dropped": dict(self.dropped), "restarts": self.restarts,
                                  "bias_limit_mm": None if self.max_bias is None
                                  else round(1e3 * self.max_bias, 3),
                                  "bias_over_limit": self.over_limit(),
                                  "treatment_withheld": dict(self.withheld),
                                  "bias_mm": np.round(self.bias * 1e3, 3).tolist()}  # fmt: skip
        if len(e):
            out |= {"measured_error_first_mm": round(float(e[0]), 3),
                    "measured_error_median_mm": round(float(np.median(e[len(e) // 2:])), 3),
                    "measured_error_last_mm": round(float(e[-1]), 3)}  # fmt: skip
        return out


def _push(history: deque, item: tuple) -> None:  # type: ignore[type-arg]
    """Append ``item`` (its time first), dropping what is older than :data:`HISTORY`."""
    if history and item[0] < history[-1][0]:
        return  # out of order: the history stays sorted
    history.append(item)
    while history and history[0][0] < item[0] - HISTORY:
        history.popleft()


def _bracket(history: deque, t: float) -> tuple[int, float] | None:  # type: ignore[type-arg]
    """Index ``i`` and weight ``w`` with ``t`` between items i and i + 1 (w of the later), or
    None when the history does not cover ``t``."""
    times = [h[0] for h in history]
    if not times or t < times[0] or t > times[-1]:
        return None
    i = int(np.searchsorted(times, t, side="right")) - 1
    if i >= len(times) - 1:
        return len(times) - 1, 0.0
    return i, (t - times[i]) / (times[i + 1] - times[i])


def _at(history: deque, t: float) -> Array | None:  # type: ignore[type-arg]
    b = _bracket(history, t)
    if b is None:
        return None
    i, w = b
    if w == 0.0:
        return np.asarray(history[i][1])
    return np.asarray((1 - w) * history[i][1] + w * history[i + 1][1])


def _frame_at(history: deque, t: float) -> tuple[Array, Array | None] | None:  # type: ignore[type-arg]
    """The tracked point at ``t`` (linear between frames; past the last frame by up to one
    frame interval, moved on along the last two), with the nearer frame's normal."""
    if len(history) >= 2 and t > history[-1][0]:
        (t0, p0, _), (t1, p1, n1) = history[-2], history[-1]
        if t - t1 <= t1 - t0:
            return p1 + (p1 - p0) * ((t - t1) / (t1 - t0)), n1
        return None
    b = _bracket(history, t)
    if b is None:
        return None
    i, w = b
    p = history[i][1] if w == 0.0 else (1 - w) * history[i][1] + w * history[i + 1][1]
    n = history[i][2] if w < 0.5 else history[i + 1][2]
    return np.asarray(p), n
