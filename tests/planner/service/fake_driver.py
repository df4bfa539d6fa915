"""A fake robot driver written with plain zenoh, for the planner-node tests (the
``node_rig`` fixture of this folder's conftest starts a node with one)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.service.node import PlannerNode

PREFIX = "exectest"
REJECTION = "q[0]: starts 0.2000 rad from the current state on joint elbow (tolerance 0.01 rad)"


class FakeDriver:
    """A robot driver in plain zenoh: token, joint states at 100 Hz (fixed ``q``), and a
    verdict in its status on every trajectory (``accept``, ``reject`` or ``silent``)."""

    def __init__(self, session: Any, robot: str, names: list[str], q: np.ndarray) -> None:
        self.session, self.robot, self.names, self.q = session, robot, names, q
        self.behaviour = "accept"
        self.arrive = False  # an accepted trajectory puts the arm on its last sample at once
        self.trajectories: list[dict[str, Any]] = []
        self._stop = threading.Event()
        self._token = session.liveliness().declare_token(f"{PREFIX}/alive/{robot}")
        self._sub = session.declare_subscriber(f"{PREFIX}/{robot}/trajectory", self._on_traj)
        self._thread = threading.Thread(target=self._publish_states, daemon=True)
        self._thread.start()

    def _publish_states(self) -> None:
        while not self._stop.wait(0.01):
            body = {"schema": "beamrelay.joint_state/1", "t": time.time(), "names": self.names,
                    "q": self.q.tolist(), "qd": [0.0] * len(self.names)}  # fmt: skip
            self.session.put(f"{PREFIX}/{self.robot}/joint_states", json.dumps(body))

    def _on_traj(self, sample: Any) -> None:
        msg = json.loads(sample.payload.to_bytes())
        self.trajectories.append(msg)
        if self.behaviour == "silent":
            return
        self.status("following", msg["id"], self.behaviour == "accept")
        if self.arrive and self.behaviour == "accept":
            self.q = np.asarray(msg["q"][-1], dtype=float)

    def status(self, mode: str, trajectory_id: str | None, accepted: bool = True) -> None:
        ack = {"id": trajectory_id, "accepted": accepted, "t": time.time(),
               "reason": None if accepted else REJECTION}  # fmt: skip
        body = {"schema": "beamrelay.status/1", "robot": self.robot, "t": time.time(),
                "mode": mode, "trajectory": ack}  # fmt: skip
        self.session.put(f"{PREFIX}/{self.robot}/status", json.dumps(body))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sub.undeclare()
        self._token.undeclare()


NodeRig = tuple[PlannerNode, Any, "FakeDriver"]
"""What the ``node_rig`` fixture makes: the node, a raw client session, the fake driver."""
NodeRigFactory = Callable[..., NodeRig]
