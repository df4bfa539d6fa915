"""The console's operator over the bus, against a running planner node: one request at a
time (a second one while the first runs is refused with BusyError, and never reaches the
planner), and Stop goes out at once, also while a request runs."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from typing import Any

import pytest

from planner.console.operator import BusyError, Operator
from planner.model.system import System
from planner.service.client import PlanClient, RequestError
from tests.drivers.conftest import wait_for
from tests.planner.raw_zenoh import Inbox
from tests.planner.service.test_node import reachable_targets, system_with_camera
from tests.planner.service.test_node_guard import PREFIX, Rig


@pytest.fixture(scope="module")
def system() -> System:
    return system_with_camera()


class HeldRig(Rig):
    """A planner node whose worker holds each request while ``gate`` is clear (``entered``
    set once one is held; ``calls``: the ids of the requests it received)."""

    def __init__(self, system: System) -> None:
        super().__init__(system)
        self.calls: list[str] = []
        self._served = self.node.serve
        self.node.serve = self._held  # type: ignore[method-assign]

    def _held(self, payload: bytes) -> bytes:
        self.calls.append(json.loads(payload)["id"])
        self.entered.set()
        self.gate.wait(60)
        return self._served(payload)


@pytest.fixture
def rig(system: System) -> Iterator[tuple[HeldRig, Operator]]:
    r = HeldRig(system)
    client = PlanClient(endpoint=r.endpoint, prefix=PREFIX)
    yield r, Operator(client)
    r.gate.set()
    client.close()
    r.close()


def answered(op: Operator, req: dict[str, Any], out: list[Any]) -> None:
    """``op.preview(req)``: its plan id, or the planner's error reply (RequestError)."""
    try:
        out.append(op.preview(req).plan["id"])
    except RequestError as exc:  # the planner answered (no robot states here): not busy
        out.append(exc)


def request(system: System, rid: str) -> dict[str, Any]:
    return {"schema": "beamrelay.request/1", "id": rid,
            "points": reachable_targets(system, 1).tolist()}  # fmt: skip


def test_a_second_request_while_one_runs_is_busy_and_never_sent(
    rig: tuple[HeldRig, Operator], system: System
) -> None:
    r, op = rig
    r.gate.clear()  # the planner holds the first request
    first: list[Any] = []
    th = threading.Thread(target=answered, args=(op, request(system, "one"), first))
    th.start()
    assert r.entered.wait(30), "the first request did not reach the planner"
    assert op.busy
    with pytest.raises(BusyError, match="a request is still running: wait for it or press Stop"):
        op.preview(request(system, "two"))
    with pytest.raises(BusyError):
        op.execute(request(system, "three"))
    r.gate.set()
    th.join(30)
    assert not op.busy and len(first) == 1 and not isinstance(first[0], BusyError)
    assert r.calls == ["one"]  # the refused ones were not sent
    later: list[Any] = []
    answered(op, request(system, "four"), later)  # free again: it reaches the planner
    assert len(later) == 1 and r.calls == ["one", "four"]


def test_stop_goes_out_at_once_while_a_request_runs(
    rig: tuple[HeldRig, Operator], system: System
) -> None:
    r, op = rig
    stops = Inbox(r.client, f"{PREFIX}/stop")
    r.gate.clear()
    th = threading.Thread(target=answered, args=(op, request(system, "held"), []))
    th.start()
    assert r.entered.wait(30)
    op.stop()  # the console's Stop does not wait for the running request
    wait_for(lambda: len(stops.bodies()) == 1, 10.0, "the stop message")
    msg = stops.bodies()[0]
    assert msg["schema"] == "beamrelay.stop/1" and msg["source"] == "console"
    assert msg["reason"] == "operator pressed Stop" and op.busy
    r.gate.set()
    th.join(30)
    stops.close()
