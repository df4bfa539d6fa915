"""Safety queries over many configurations aiming at targets (path samples): which of them
break a rule (:func:`unsafe_samples`), and whether the path NLP's result breaks the rules
more often than its warm start (:func:`safer_warm_start`). Joints stacked in rad, points in
the world frame, metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.beam.trace import trace_beam
from planner.model.system import Targets
from planner.model.transforms import Array
from planner.safety.beam_cover import configs
from planner.safety.model import Safety


def unsafe_samples(safety: Safety, Q: Array, points: Array, normals: Array | None) -> Array:
    """(K,) True where the configuration Q[k] (stacked rad) aiming at ``points[k]`` (world)
    breaks a safety rule; NaN rows are not counted."""
    system, out = safety.system, np.zeros(len(Q), dtype=bool)
    p0 = system.world_T_laser[:3, 3]
    ks = np.flatnonzero(np.all(np.isfinite(Q), axis=1))
    P = []
    for k in ks:
        n = None if normals is None or not np.all(np.isfinite(normals[k])) else normals[k]
        ev = trace_beam(system, Q[k], points[k], n)
        P.append(np.vstack([p0, ev.hits, ev.spot]))
    if len(ks):
        out[ks] = [v is not None for v in configs(safety, Q[ks], np.array(P))]
    return out


def safer_warm_start(
    safety: Safety, Q_nlp: Array, Q_warm: Array, ks: Any, targets: Targets,
    bad_nlp: int | None = None,
) -> bool:  # fmt: skip
    """True when the path NLP's samples ``ks`` break the safety rules more often than their
    warm start (then the warm start is kept); ``bad_nlp``: at how many samples ``Q_nlp``
    breaks them, when the caller already counted (:func:`unsafe_samples` otherwise)."""
    P = targets.points[ks]
    N = None if targets.normals is None else targets.normals[ks]
    if bad_nlp is None:
        bad_nlp = int(unsafe_samples(safety, Q_nlp, P, N).sum())
    return bad_nlp > 0 and bad_nlp > int(unsafe_samples(safety, Q_warm, P, N).sum())
