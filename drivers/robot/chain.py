"""The other arms of the beam chain, as the gate's driver sees them on the bus.

The laser's beam reaches a target only through every mirror of the chain, so the gate's
driver (:class:`drivers.robot.node.RobotNode` with ``chain``) treats a laser interval as
valid only while every other chain arm is *live and following*. :class:`ChainWatch`
records, from Zenoh callbacks, each chain arm's liveliness token
(``<prefix>/alive/<robot>``), the receive time (monotonic s) of its last
``<prefix>/<robot>/joint_states`` (250 Hz) and its last ``<prefix>/<robot>/status`` (at
once on every change of mode, protective stop or fault; else 10 Hz). :meth:`ChainWatch.fault`
says, every control period, why the chain is not live (None: it is):

- its token is gone (a killed driver: Zenoh drops it within a few ms) or never seen;
- no joint state for :data:`STATE_TIMEOUT` (a hung driver or a cut link);
- its status is protective-stopped, or braking, stopped or faulted;
- its status is in another mode than those that play a motion (:data:`LIVE_MODES`; idle)
  while it already answered this arm's request (it finished, or refused it), or for more
  than :data:`START_GRACE` after this arm started playing (its verdict on the same request
  may come a little later than this arm's: a laser interval at the very start of a
  trajectory must not race it).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.bus.ids import base_id
from planner.bus.session import decode
from schemas.messages import RobotStatus

#: longest silence (s, receive clock) of a chain arm's joint states (250 Hz: 12 missed)
STATE_TIMEOUT = 0.050
#: status modes of a chain arm that plays a trajectory or a setpoint stream
LIVE_MODES = frozenset({"approach", "following", "settle", "streaming"})
#: status modes of a chain arm that has stopped
HALTED_MODES = frozenset({"braking", "stopped", "fault"})
#: longest time (s) a chain arm may still be idle once this arm plays a request
START_GRACE = 0.100


class ChainWatch:
    """Liveliness, joint-state freshness and status of the other arms of the beam chain."""

    def __init__(self, robots: tuple[str, ...], clock: Callable[[], float] = time.monotonic):
        self.robots = tuple(robots)
        self.clock = clock
        self.alive: dict[str, bool] = dict.fromkeys(self.robots, False)
        self.state_at: dict[str, float] = dict.fromkeys(self.robots, -np.inf)
        self.status: dict[str, RobotStatus | None] = dict.fromkeys(self.robots, None)
        self.n_bad = 0  # bodies that did not decode

    # -- callbacks (Zenoh threads) ----------------------------------------------------------
    def on_alive(self, robot: str) -> Callable[[Any], None]:
        def cb(sample: Any) -> None:
            import zenoh

            self.alive[robot] = sample.kind == zenoh.SampleKind.PUT

        return cb

    def on_state(self, robot: str) -> Callable[[Any], None]:
        def cb(_sample: Any) -> None:
            self.state_at[robot] = self.clock()

        return cb

    def on_status(self, robot: str) -> Callable[[Any], None]:
        def cb(sample: Any) -> None:
            try:
                self.status[robot] = decode(sample.payload.to_bytes(), RobotStatus)
            except Exception:  # a bad status is no status: the last good one stands
                self.n_bad += 1

        return cb

    # -- the control loop -------------------------------------------------------------------
    def fault(
        self, now: float | None = None, request: str | None = None, since: float | None = None
    ) -> str | None:
        """Why a chain arm is not live and following (None: all are); ``now`` monotonic s,
        ``request`` the id (chunk suffix removed) this arm plays since ``since`` (monotonic
        s; None: this arm plays nothing)."""
        now = self.clock() if now is None else now
        for robot in self.robots:
            if not self.alive[robot]:
                return f"{robot}'s liveliness token is gone"
            silent = now - self.state_at[robot]
            if silent > STATE_TIMEOUT:
                heard = "none heard" if np.isinf(silent) else f"silent for {1e3 * silent:.0f} ms"
                return f"{robot}'s joint states: {heard}"
            status = self.status[robot]
            if status is None:
                return f"{robot}: no status heard"
            if status.protective_stop:
                return f"{robot} is protective-stopped"
            if status.mode in LIVE_MODES:
                continue
            ack = status.trajectory
            answered = ack is not None and request is not None and base_id(ack.id) == request
            late = since is None or now - since > START_GRACE
            if status.mode in HALTED_MODES or answered or late:
                why = f" ({status.fault})" if status.fault else ""
                return f"{robot} is {status.mode}{why}, not following"
        return None
