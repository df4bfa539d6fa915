"""Arm, then fire: Execute runs only the request armed, once, within the window; edits, new
faults, STOP and the window's end drop the arming. The rules on a fake clock, then the page's
handlers (widgets and the planner stubbed) showing that Execute without Arm sends nothing."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any
from unittest.mock import MagicMock

import pytest

from planner.console.app import Console
from planner.console.arming import ARM_WINDOW, HEARTBEAT, PROTECTIVE_STOP, Arming, treatment
from planner.console.live import Stamped
from planner.console.session import Session
from planner.data import shipped_scenario
from tests.planner.console.test_console_handlers import panel
from tests.planner.service.plans import as_plan


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def req(*points: float, dwell: float = 0.4) -> dict[str, Any]:
    return {"id": "x", "execute": True, "targets": [{"p": [p, 0, 0]} for p in points],
            "dwell": dwell}  # fmt: skip


def test_execute_needs_the_same_request_armed_within_the_window_once() -> None:
    clock = Clock()
    a = Arming(clock)
    assert "not armed" in (a.fire(req(1.0)) or "")
    armed = a.arm(req(1.0) | {"execute": False, "id": "y"}, "1/1 targets", {})
    assert not isinstance(armed, str)
    clock.t += ARM_WINDOW - 0.01
    assert a.fire(req(1.0)) is None  # id and the execute flag are not the motion
    assert "not armed" in (a.fire(req(1.0)) or "")  # once
    a.arm(req(1.0), "", {})
    clock.t += ARM_WINDOW + 0.01
    refused = a.fire(req(1.0)) or ""
    assert "not armed" in refused and "30 s arming window ran out" in refused
    for other in (req(1.0, 2.0), req(1.5), req(1.0, dwell=5.0)):
        a.arm(req(1.0), "", {})
        assert "changed after Arm" in (a.fire(other) or "")
        assert a.armed is None and "changed" in a.dropped


def test_new_faults_drop_the_arming_old_ones_do_not() -> None:
    a = Arming(Clock())
    old = {"arm0": "operator stop"}  # the stop that ended the last motion
    assert not isinstance(a.arm(req(1.0), "", old), str)
    a.watch(old)
    assert a.armed is not None
    a.watch(old | {"arm1": "joint limit"})
    assert a.armed is None and a.dropped == "arm1: joint limit"
    assert not isinstance(a.arm(req(1.0), "", {}), str)
    a.watch({"arm0": "operator stop"})  # a fault that came after Arm
    assert a.armed is None and a.dropped == "arm0: operator stop"
    for blocking in ({HEARTBEAT: "silent"}, {"arm0": PROTECTIVE_STOP}):
        assert isinstance(a.arm(req(1.0), "", blocking), str)
        assert a.armed is None
        assert "not armed" in (a.fire(req(1.0)) or "")
    a.arm(req(1.0), "", {})
    a.drop("STOP")
    assert a.fire(req(1.0)) == "not armed (STOP): press Arm, check what it will do, then Execute"


def test_the_summary_says_what_execute_will_do() -> None:
    plan = {
        "targets": [{}, {}, {}],
        "solutions": [{"status": "ok"}, {"status": "ok"}, {"status": "failed"}],
        "trajectory": {"t": [0.5, 4.0], "laser_on": [[1.0, 2.0], [3.0, 3.5]]},
    }
    text = treatment(as_plan(plan), 0.005)
    assert text == ("2/3 targets, motion 3.5 s, treatment laser on 1.50 s, energy 0.0075 J at "
                    "0.005 W")  # fmt: skip
    assert "energy" not in treatment(as_plan(plan), None)
    assert "laser on 0.00 s" in treatment(as_plan({"trajectory": {"t": [0.0, 1.0]}}), None)


class FakeOperator:
    def __init__(self) -> None:
        self.executed: list[dict[str, Any]] = []
        self.previews = 0

    def preview(self, request: dict[str, Any]) -> Any:
        self.previews += 1
        plan = {"targets": [{}], "solutions": [{"status": "ok"}],
                "trajectory": {"t": [0.0, 2.0], "laser_on": [[1.0, 1.4]]}}  # fmt: skip
        return SimpleNamespace(plan=as_plan(plan))

    def execute(self, request: dict[str, Any]) -> Any:
        self.executed.append(request)
        return SimpleNamespace(plan=as_plan({}))

    def stop(self, reason: str = "") -> None:
        pass


class FakeLive:
    def __init__(self, status: dict[str, Any], heartbeat_at: float | None) -> None:
        self.status, self.heartbeat_at = status, heartbeat_at

    def snapshot(self) -> dict[str, Any]:
        import time

        hb = None if self.heartbeat_at is None else Stamped(None, time.monotonic())
        return {"status": self.status, "heartbeat": hb}


def status(fault: str | None = None, protective_stop: bool = False) -> Stamped:
    return Stamped(SimpleNamespace(fault=fault, protective_stop=protective_stop), 0.0)


@pytest.fixture
def page() -> tuple[Session, FakeOperator, FakeLive]:
    console = Console(shipped_scenario("s_curve.yaml"))
    console.operator, console.live = FakeOperator(), FakeLive({}, 0.0)  # type: ignore[assignment]
    console.server = MagicMock()
    c = Session(console, panel(), MagicMock())
    console.sessions[1] = c
    c.targets = c.targets.add([0.1, 0.2, 0.3], None)

    def shown(answer: Any, executed: bool) -> None:
        c.preview = SimpleNamespace(n_ok=len(answer.plan.solutions))  # type: ignore[assignment]
        c.panel.result.content = "preview shown" if not executed else "executed"

    c.show_answer = shown  # type: ignore[method-assign]
    console.follow_live = lambda: None  # type: ignore[method-assign]
    return c, console.operator, console.live  # type: ignore[return-value]


def test_the_page_executes_only_after_arm(page: tuple[Session, FakeOperator, FakeLive]) -> None:
    c, op, live = page
    c.do_execute()
    assert op.executed == [] and "not armed" in c.panel.result.content
    c.do_arm()
    assert "ARMED for 30 s" in c.panel.result.content
    assert "1/1 targets, motion 2.0 s, treatment laser on 0.40 s" in c.panel.result.content
    assert "arming: **ARMED**" in c.arming_text()
    c.do_execute()
    assert len(op.executed) == 1 and op.executed[0]["execute"] is True
    c.do_execute()  # the arming was used
    assert len(op.executed) == 1 and "not armed" in c.panel.result.content
    c.do_arm()
    c.edit_list(lambda t: t.add([0.2, 0.2, 0.3], None))  # a click after Arm
    c.do_execute()
    assert len(op.executed) == 1 and "target list changed" in c.panel.result.content
    c.do_arm()
    live.status = {"arm0": status("joint limit")}
    c.watch_arming()
    assert "disarmed" in c.panel.result.content and "arm0: joint limit" in c.panel.result.content
    c.do_execute()
    assert len(op.executed) == 1
    live.status = {"arm0": status(protective_stop=True)}
    c.do_arm()
    assert "not armed: arm0: protective stop" in c.panel.result.content
    live.status, live.heartbeat_at = {}, None
    c.do_arm()
    assert "not armed: heartbeat: the planner's heartbeat is silent" in c.panel.result.content
