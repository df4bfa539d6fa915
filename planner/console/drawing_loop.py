"""The console's drawing thread: newest cloud, robots, live beam, spot, health.

Each tick sends only what changed: a cloud frame newer than the last one drawn (decoded,
mapped and decimated by :func:`planner.console.cloud.cloud_from_sample`), the robots and the
beam when the joints moved (unless the operator is scrubbing a planned trajectory), the spot
marker when the camera reports one. The health panel is refreshed at its own, lower rate.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.console.session import SPOT_COLOUR
from planner.errors import InputError

if TYPE_CHECKING:
    from planner.console.app import Console

#: at most this many cloud frames per second go to the browser (the camera sends 15)
CLOUD_RATE = 10.0
#: joints that moved less than this (rad, every joint) are not redrawn
REDRAW_Q = 1e-5
POINT_SIZE = 0.004  # m


def next_due(due: float, now: float, period: float) -> float:
    """When (s) the next cloud frame may go, one having gone at ``now`` that was due at
    ``due``: a period after ``due``, so that waiting for the drawing tick and for the
    camera's next frame does not add up (taking the first new frame at least a period after
    the last one sent 15 Hz frames at ~7.5/s), but never sooner than ``now``: a frame late
    by more than a period lets only one more go at once."""
    return max(due, now - period) + period


class DrawLoop:
    """One drawing thread of a :class:`~planner.console.app.Console`."""

    def __init__(self, console: Console) -> None:
        self.c = console
        self.seq = 0
        self.q_drawn: dict[str, Any] | None = None
        self.cloud_node: Any = None
        self.cloud_due = 0.0
        self.spot_node: Any = None

    def run(self, stop: threading.Event, period: float, health_period: float) -> None:
        next_health = 0.0
        while not stop.wait(period):
            try:
                self.tick()
                if time.monotonic() >= next_health:
                    self.health()
                    next_health = time.monotonic() + health_period
            except Exception as exc:  # the page must keep drawing whatever one frame holds
                for session in list(self.c.sessions.values()):
                    session.panel.stats.content = f"drawing error: {type(exc).__name__}: {exc}"

    def health(self) -> None:
        """Every browser's health panel (the bus's health and its own arming) and stats."""
        health = self.c.health_text()
        for session in list(self.c.sessions.values()):
            session.watch_arming()
            session.watch_verdicts()
            session.panel.health.content = f"{health}  \n{session.arming_text()}"
            session.show_stats()

    def tick(self) -> None:
        c = self.c
        q = c.live.joint_vector(c.system.robot_names)
        self.cloud(q)
        if q is not None and not c.scrubbing and self._moved(q):
            c.pose(q)
            self.q_drawn = q
        self.spot()

    def _moved(self, q: dict[str, Any]) -> bool:
        if self.q_drawn is None:
            return True
        return any(float(np.max(np.abs(q[r] - self.q_drawn[r]))) > REDRAW_Q for r in q)

    def cloud(self, q: dict[str, Any] | None) -> None:
        c = self.c
        now = time.monotonic()
        if now < self.cloud_due:
            return
        seq, raw = c.live.take_points(self.seq)
        if raw is None:
            return
        self.cloud_due = next_due(self.cloud_due, now, 1.0 / CLOUD_RATE)
        self.seq = seq
        try:
            cloud = c.new_cloud(raw[0], raw[1], q)
        except InputError:
            c.live.rejected += 1
            return
        c.cloud = cloud
        if self.cloud_node is not None and len(self.cloud_node.points) == len(cloud.points):
            self.cloud_node.points = cloud.points
            self.cloud_node.colors = cloud.colors
        else:
            self.cloud_node = c.server.scene.add_point_cloud(
                "/cloud", cloud.points, cloud.colors, point_size=POINT_SIZE, point_shape="square"
            )
        c.cloud_frames += 1

    def spot(self) -> None:
        c = self.c
        snap = c.live.spot
        if snap is None or snap.value.p_camera is None or time.monotonic() - snap.at > 0.5:
            if self.spot_node is not None:
                self.spot_node.visible = False
            return
        T = c.world_T_camera(c.live.joint_vector(c.system.robot_names))
        p = T[:3, :3] @ np.asarray(snap.value.p_camera, dtype=float) + T[:3, 3]
        if self.spot_node is None:
            self.spot_node = c.server.scene.add_icosphere("/spot", radius=0.005, color=SPOT_COLOUR)
        self.spot_node.position = p
        self.spot_node.visible = True
