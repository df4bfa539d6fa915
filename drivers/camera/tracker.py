"""Simulated marker tracker: the moving targets of a scenario, seen by the D435, on the bus.

Tracked points: the scenario's ``targets.points`` (world frame) that lie on a scene object
with a ``motion:`` (within :data:`planner.model.scene.ON_SURFACE` of its surface at rest), one stream per such
object, ``id`` = the object's name. At time ``t`` (the simulation clock,
:mod:`planner.model.motion`) each point is where the motion puts it, seen through the
marker noise of the simulated camera's spot model (:class:`planner.track.noise.MarkerNoise`
with :data:`drivers.camera.sim.SIGMA_PX` and :data:`drivers.camera.sim.SPOT_WINDOW`) from
the *true* camera pose; normals (when the scenario gives them) turn with the object. No
occlusion test: a marker is always seen.

:class:`TrackerNode` publishes :class:`schemas.messages.TargetStream` on
``<prefix>/targets/stream`` (liveliness token ``<prefix>/alive/tracker``) at ``rate`` (30 Hz, the camera's), each message ``latency`` s
after its capture time ``t`` (which it carries), as a marker tracker's processing would.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.camera.sim import SIGMA_PX, SPOT_WINDOW
from drivers.loop_node import LoopNode
from planner.bus.session import JSON, Keys, encode
from planner.model.scene import TrackedObject
from planner.model.transforms import Array
from planner.track.noise import MarkerNoise
from schemas.messages import TargetStream

#: s: default time from a frame's capture to its message
LATENCY = 0.02


class SimTracker:
    """Noisy views of the tracked objects at time ``t`` (see the module docstring)."""

    def __init__(
        self, objects: list[TrackedObject], world_T_camera: Array, fx: float, seed: int | None
    ) -> None:
        self.objects = objects
        self.world_T_camera = np.asarray(world_T_camera, dtype=float)
        self.noise = MarkerNoise(fx=fx, centroid_px=SIGMA_PX, window_px=SPOT_WINDOW)
        self.rng = np.random.default_rng(seed)

    def true_points(self, obj: TrackedObject, t: float) -> Array:
        """The object's targets at ``t`` (s), world, m."""
        assert obj.item.motion is not None
        return obj.item.motion.move_points(obj.points, obj.item.world_T_object[:3, 3], t)

    def true_normals(self, obj: TrackedObject, t: float) -> Array | None:
        """The object's target normals at ``t`` (s), world (None without normals)."""
        assert obj.item.motion is not None
        return None if obj.normals is None else obj.normals @ obj.item.motion.rotation(t).T

    def measure(self, t: float) -> list[TargetStream]:
        """One message per tracked object for a frame captured at ``t`` (s)."""
        R, c = self.world_T_camera[:3, :3], self.world_T_camera[:3, 3]
        out = []
        for obj in self.objects:
            seen = [
                R @ self.noise.sample_camera(R.T @ (p - c), self.rng) + c
                for p in self.true_points(obj, t)
            ]
            n = self.true_normals(obj, t)
            normals = None if n is None else n.tolist()
            out.append(TargetStream(t=t, id=obj.item.name, points=[s.tolist() for s in seen],
                                    normals=normals))  # fmt: skip
        return out


class TrackerNode(LoopNode):
    """Publishes a :class:`SimTracker`'s messages at ``rate`` Hz, ``latency`` s late."""

    def __init__(
        self,
        session: Any,
        keys: Keys,
        tracker: SimTracker,
        *,
        rate: float = 30.0,
        latency: float = LATENCY,
        clock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__()
        if not 0 <= latency < 1.0 / rate:
            raise ValueError(f"latency {latency:g} s must be in [0, {1 / rate:g}) s (one frame)")
        self.session, self.keys, self.tracker = session, keys, tracker
        self.period, self.latency, self.clock = 1.0 / rate, latency, clock
        self.frames = 0

    def start(self) -> TrackerNode:

        self._pub = self.session.declare_publisher(self.keys.target_stream, encoding=JSON)
        self._handles.append(self._pub)
        self._handles.append(self.session.liveliness().declare_token(self.keys.alive("tracker")))
        self._start_loop("tracker")
        return self

    def _loop(self) -> None:

        next_t = time.monotonic()
        while not self._stop.is_set():
            msgs = self.tracker.measure(self.clock())
            if self._stop.wait(self.latency):
                return
            for msg in msgs:
                self._pub.put(encode(msg))
            self.frames += 1
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            else:
                next_t = time.monotonic()
