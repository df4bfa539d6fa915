"""The console's requests to the running system, over the planner's public interface.

Preview = a TargetRequest with ``trajectory: true`` (the planner plans the trajectory from
the robots' current state, as it would for ``execute``, and sends nothing); execute = the
same request with ``execute: true`` through :meth:`planner.service.client.PlanClient.execute`
(which waits for the motion and measures the spot of every target; for a path, the spots
seen during the motion are compared with it: :mod:`planner.console.sweep`); stop = a
:class:`~schemas.messages.StopMessage` on ``<prefix>/stop``. One request at a time.
"""

from __future__ import annotations

import threading
import time
from typing import Any, NamedTuple

from planner.bus.session import JSON, encode, urgent
from planner.console.sweep import Sweep, sweep_of
from planner.io.plan import Plan, Verdict
from planner.model.transforms import Array
from planner.service.client import PlanClient, world_T_camera_of
from schemas.messages import StopMessage

#: seconds to wait for a plan reply
PLAN_TIMEOUT = 30.0


class Answer(NamedTuple):
    """A reply: the :class:`~planner.io.plan.Plan`, the round trip (s), the measured spots
    (world, m; None where unseen) if executed, and for an executed path what the camera saw
    of it (None otherwise)."""

    plan: Plan
    seconds: float
    spots: list[Array | None] | None
    sweep: Sweep | None = None


class Operator:
    """Sends the console's requests on one :class:`PlanClient`."""

    def __init__(self, client: PlanClient) -> None:
        self.client = client
        self._busy = threading.Lock()

    @property
    def busy(self) -> bool:
        return self._busy.locked()

    def preview(self, req: dict[str, Any]) -> Answer:
        """Plan ``req`` with its trajectory, without moving anything. RequestError on an
        error reply; BusyError while another request runs."""
        with self._claim():
            t0 = time.perf_counter()
            plan = self.client.plan({**req, "execute": False, "trajectory": True},
                                    PLAN_TIMEOUT)  # fmt: skip
            dt = time.perf_counter() - t0
        return Answer(plan, dt, None)

    def execute(self, req: dict[str, Any]) -> Answer:
        """Plan and execute ``req``, wait for the motion, measure the spots (and the marked
        path, for a path request)."""
        with self._claim():
            t0, since = time.perf_counter(), time.monotonic()
            plan, spots = self.client.execute_plan({**req, "execute": True}, PLAN_TIMEOUT)
            dt = time.perf_counter() - t0
        sweep = self._sweep(plan, since) if req.get("mode") == "path" else None
        return Answer(plan, dt, spots, sweep)

    def _sweep(self, plan: Plan, since: float) -> Sweep | None:
        """The marked path of an executed ``plan`` from the spots recorded since ``since``
        (monotonic s); None when rejected or the camera is not fixed in the world."""
        world_T_camera = world_T_camera_of(plan)
        if plan.execution is not Verdict.ACCEPTED or world_T_camera is None:
            return None
        rec = self.client.recorder
        with rec.lock:
            seen = [(s.p_camera, s.q) for s in rec.spots if s.arrived >= since]
        return sweep_of(plan, seen, world_T_camera)

    def stop(self, reason: str = "operator pressed Stop") -> None:
        """Publish ``<prefix>/stop``: every driver brakes and switches the laser off."""
        msg = StopMessage(t=time.time(), source="console", reason=reason)
        self.client.session.put(self.client.keys.stop, encode(msg), encoding=JSON, **urgent())

    def _claim(self) -> Any:
        if not self._busy.acquire(blocking=False):
            raise BusyError("a request is still running: wait for it or press Stop")
        return _Release(self._busy)


class BusyError(RuntimeError):
    """Another request of this console is still running."""


class _Release:
    def __init__(self, lock: threading.Lock) -> None:
        self.lock = lock

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        self.lock.release()
