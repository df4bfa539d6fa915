"""Spot measurements: camera frames averaged, confidence-weighted, mapped to the world.

A camera frame's detection is a point in the camera's optical frame (m) with a confidence in
(0, 1], or nothing. :func:`average_frames` maps the seen ones to the world through the
*calibrated* ``world_T_camera`` (the planner's model of the camera pose, not the truth) and
averages them with the confidences as weights. :class:`Measure` is what the servo loop calls:
it moves the arm(s) to a configuration and returns such an average.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from planner.model.transforms import Array


@dataclass(frozen=True)
class SpotFrame:
    """One camera frame's detection: ``p_camera`` (3, m, optical frame) or None (no spot),
    and its ``confidence`` in [0, 1]."""

    p_camera: Array | None
    confidence: float = 1.0


@dataclass(frozen=True)
class SpotMeasurement:
    """A spot averaged over camera frames, world frame (m).

    ``frames`` is how many frames were grabbed, ``seen`` how many had a spot;
    ``confidence`` is the mean confidence of the seen ones and ``spread`` (m) their
    confidence-weighted RMS distance from ``spot_world``.
    """

    spot_world: Array
    frames: int
    seen: int
    confidence: float
    spread: float


class Measure(Protocol):
    """Move the arm(s) to stacked joints ``q`` (rad), grab ``frames`` camera frames and
    return their average (:func:`average_frames`), or None when the spot was not seen."""

    def __call__(self, q: Array, frames: int) -> SpotMeasurement | None: ...


def average_frames(frames: Sequence[SpotFrame], world_T_camera: Array) -> SpotMeasurement | None:
    """The confidence-weighted mean of the frames that saw a finite spot, in the world (m),
    through ``world_T_camera`` (4 x 4); None when no frame saw one. Frames with a
    non-finite point or a confidence outside (0, 1] count as unseen."""
    T = np.asarray(world_T_camera, dtype=float)
    pts, w = [], []
    for f in frames:
        if f.p_camera is None:
            continue
        p = np.asarray(f.p_camera, dtype=float)
        c = float(f.confidence)
        if p.shape != (3,) or not np.all(np.isfinite(p)) or not (0.0 < c <= 1.0):
            continue
        pts.append(T[:3, :3] @ p + T[:3, 3])
        w.append(c)
    if not pts:
        return None
    P, W = np.array(pts), np.array(w)
    mean = W @ P / W.sum()
    spread = float(np.sqrt(W @ np.sum((P - mean) ** 2, axis=1) / W.sum()))
    return SpotMeasurement(mean, len(frames), len(pts), float(W.mean()), spread)


def merge(a: SpotMeasurement, b: SpotMeasurement) -> SpotMeasurement:
    """Two measurements of one spot as one: the mean weighted by frames seen x confidence
    (as :func:`average_frames` weighs frames), their pooled spread about it."""
    wa, wb = a.seen * a.confidence, b.seen * b.confidence
    mean = (wa * a.spot_world + wb * b.spot_world) / (wa + wb)
    da, db = a.spot_world - mean, b.spot_world - mean
    var = (wa * (a.spread**2 + da @ da) + wb * (b.spread**2 + db @ db)) / (wa + wb)
    seen = a.seen + b.seen
    return SpotMeasurement(mean, a.frames + b.frames, seen, (wa + wb) / seen,
                           float(np.sqrt(var)))  # fmt: skip


@dataclass(frozen=True)
class SpotGate:
    """Which camera frames count: a confidence of at least ``min_confidence`` and a spot
    within ``radius`` (m, world) of the predicted one."""

    min_confidence: float
    radius: float


def gate_frames(frames: Sequence[SpotFrame], world_T_camera: Array, predicted_world: Array,
                gate: SpotGate) -> tuple[list[SpotFrame], int, int]:  # fmt: skip
    """The frames that pass ``gate`` (a frame without a spot passes as unseen), how many had
    too low a confidence and how many were too far from ``predicted_world`` (m)."""
    T = np.asarray(world_T_camera, dtype=float)
    pred = np.asarray(predicted_world, dtype=float)
    kept: list[SpotFrame] = []
    weak = far = 0
    for f in frames:
        if f.p_camera is None:
            kept.append(f)
            continue
        p = np.asarray(f.p_camera, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            kept.append(SpotFrame(None, 0.0))
        elif not float(f.confidence) >= gate.min_confidence:
            weak += 1
        elif np.linalg.norm(T[:3, :3] @ p + T[:3, 3] - pred) > gate.radius:
            far += 1
        else:
            kept.append(f)
    return kept, weak, far
