"""The camera's live point cloud as a surface for camera-frame targets.

:class:`LiveCloud` keeps the newest ``<prefix>/camera/points`` sample as it came (its Zenoh
buffers, not decoded: the planner's callbacks never spend a frame's decode time), and
:meth:`LiveCloud.around` decodes it only when a request asks: the cloud's points near the
targets, in the world through the calibrated camera pose. Those are what
:func:`planner.plan.landing.cloud_landings` lands camera-frame targets on where the scene
has no surface carrying them (a face, a hand: what the scenario does not model).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.errors import InputError
from planner.model.transforms import Array
from schemas.points import decode_points

log = logging.getLogger("beamrelay.cloud")

#: s: an older cloud is not a surface (the scene may have moved)
MAX_AGE = 1.0
#: m: the cloud is kept this far around each target
AROUND = 0.03


class LiveCloud:
    """The newest camera cloud (subscriber callback :meth:`callback`)."""

    def __init__(self, max_age: float = MAX_AGE, clock: Callable[[], float] = time.monotonic):
        self.max_age, self.clock = max_age, clock
        self._lock = threading.Lock()
        self._latest: tuple[float, Any, Any] | None = None  # receipt time, payload, attachment

    def callback(self, sample: Any) -> None:
        """Subscriber callback of ``<prefix>/camera/points``: keep the sample's buffers."""
        with self._lock:
            self._latest = (self.clock(), sample.payload, sample.attachment)

    def around(self, points: Array, world_T_camera: Array, radius: float = AROUND) -> Array | None:
        """The newest cloud's points (world, m) within ``radius`` of any of ``points``
        (world, m), or None without a fresh, well-formed cloud (a bad one is logged)."""
        with self._lock:
            latest = self._latest
        if latest is None or self.clock() - latest[0] > self.max_age:
            return None
        _, payload, attachment = latest
        if attachment is None:
            log.warning("bad cloud: no attachment")
            return None
        try:
            data, _ = decode_points(payload.to_bytes(), attachment.to_bytes())
        except InputError as exc:
            log.warning("bad cloud: %s", exc)
            return None
        xyz = np.asarray(data[:, :3], dtype=float)
        xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
        world = xyz @ world_T_camera[:3, :3].T + world_T_camera[:3, 3]
        targets = np.asarray(points, dtype=float).reshape(-1, 3)
        lo, hi = targets.min(axis=0) - radius, targets.max(axis=0) + radius
        world = world[np.all((world >= lo) & (world <= hi), axis=1)]  # the box first: cheap
        keep = np.zeros(len(world), dtype=bool)
        for p in targets:
            keep |= np.sum((world - p) ** 2, axis=1) <= radius**2
        return world[keep]
