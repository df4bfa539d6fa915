"""The one rule of a valid beam chain, and its thresholds (defined here, once).

A chain is valid when, at every mirror, the beam meets the front face (``front = -n.v``
above :data:`MIN_FRONT`), the mirror lies ahead of the ray (ray parameter ``t`` above
:data:`MIN_AHEAD`, metres) and the hit lies inside the region of interest (margin
``roi_half - |uv|`` at least :data:`MIN_ROI_MARGIN`, metres), and the target lies ahead of
the last ray (its ray parameter above :data:`MIN_AHEAD`). The planner's traces
(:class:`planner.beam.trace.BeamTrace`, the IK, the path, the occlusion retries) apply it
with no slack; the independent checker (:mod:`planner.verify`) applies the same rule with its
:data:`~planner.verify.tolerances.TRACE_SLACK`, because two float computations of one
geometry differ by rounding. The predicates work elementwise on arrays.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

MIN_FRONT = 1e-9  # -n.v (cosine of the angle to the mirror normal): front face
MIN_AHEAD = 1e-6  # m: ray parameter of a mirror hit, and of the target on the last ray
MIN_ROI_MARGIN = 0.0  # m: roi_half - |uv| of a hit inside the region of interest

Mask = npt.NDArray[np.bool_]


def front_ok(front: Any, slack: float = 0.0) -> Mask:
    """``front = -n.v`` (cosine) on the front face: above :data:`MIN_FRONT` less ``slack``."""
    return np.asarray(np.asarray(front, dtype=float) > MIN_FRONT - slack)


def ahead_ok(t: Any, slack: float = 0.0) -> Mask:
    """Ray parameter ``t`` (m) of a mirror hit or target ahead: above :data:`MIN_AHEAD`
    less ``slack`` (m)."""
    return np.asarray(np.asarray(t, dtype=float) > MIN_AHEAD - slack)


def roi_ok(margin: Any, slack: float = 0.0) -> Mask:
    """ROI margin ``roi_half - |uv|`` (m) inside: at least :data:`MIN_ROI_MARGIN` less
    ``slack`` (m)."""
    return np.asarray(np.asarray(margin, dtype=float) >= MIN_ROI_MARGIN - slack)


def chain_ok(front: Any, ahead: Any, roi: Any, target_ahead: Any, slack: float = 0.0) -> bool:
    """Every reflection valid (front face, ahead, inside the ROI) and the target ahead."""
    return bool(
        front_ok(front, slack).all()
        and ahead_ok(ahead, slack).all()
        and roi_ok(roi, slack).all()
        and ahead_ok(target_ahead, slack).all()
    )
