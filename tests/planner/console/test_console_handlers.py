"""The console's STOP button and preview-on-click, at the Python level: the handlers the
page's button and clicks call, with the widgets and the 3D scene stubbed (the page itself
is tested in a browser elsewhere) and the operator on a real bus."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any
from unittest.mock import MagicMock

import numpy as np
import pytest

from planner.bus.session import open_session
from planner.console.app import Console
from planner.console.cloud import Cloud
from planner.console.operator import Operator
from planner.console.panel import Panel
from planner.console.session import Session
from planner.console.targets import Mode
from planner.data import shipped_scenario
from planner.service.client import PlanClient
from tests.drivers.conftest import free_port, wait_for
from tests.planner.raw_zenoh import Inbox

PREFIX = "consoletest"


class Widget:
    """A GUI handle: ``value``, ``content``, and the callbacks viser would call."""

    def __init__(self, value: Any = None) -> None:
        self.value, self.content = value, ""
        self.max, self.disabled = 0.0, False
        self.clicked: list[Callable[[Any], None]] = []

    def on_click(self, fn: Callable[[Any], None]) -> None:
        self.clicked.append(fn)

    def on_update(self, fn: Callable[[Any], None]) -> None:
        pass

    def click(self) -> None:
        for fn in self.clicked:
            fn(None)


def panel() -> Panel:
    values = {"mode": Mode.POINTS.value, "normals": True, "auto_preview": True, "selected": 0,
              "dwell": 0.0, "closed_loop": False}  # fmt: skip
    return Panel(**{name: Widget(values.get(name)) for name in Panel.__dataclass_fields__})


@pytest.fixture
def console() -> Iterator[tuple[Session, Inbox]]:
    """One browser's session of a console, wired to stub widgets and a stub scene, the
    console's operator on a private bus; an inbox of ``<prefix>/stop`` on that bus."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_session(listen=True, endpoint=endpoint)
    c = Console(shipped_scenario("s_curve.yaml"), endpoint=endpoint, prefix=PREFIX)
    c.client = PlanClient(endpoint=endpoint, prefix=PREFIX)
    c.operator = Operator(c.client)
    c.server = MagicMock()
    session = Session(c, panel(), MagicMock()).wire()
    c.sessions[1] = session
    stops = Inbox(hub, f"{PREFIX}/stop")
    yield session, stops
    stops.close()
    c.client.close()
    hub.close()


def test_the_stop_button_publishes_stop_and_says_so(
    console: tuple[Session, Inbox], caplog: pytest.LogCaptureFixture
) -> None:
    c, stops = console
    with caplog.at_level(logging.INFO, logger="beamrelay.console"):
        c.panel.stop.click()
        wait_for(lambda: len(stops.bodies()) == 1, 10.0, "the stop message")
        msg = stops.bodies()[0]
        assert (msg["schema"], msg["source"], msg["reason"]) == (
            "beamrelay.stop/1", "console", "operator pressed Stop")  # fmt: skip
        assert c.panel.result.content == "**STOP sent**: every robot brakes, laser off"
        c.panel.clear.click()  # a list edit, not an operator action: not logged
        c.panel.plan.click()  # logged, then refused (no targets)
    # the operator's presses are an audit trail, in the console's log
    pressed = [r.getMessage() for r in caplog.records if r.name == "beamrelay.console"]
    assert pressed == ["pressed action=stop", "pressed action=preview"], pressed


def grid() -> Cloud:
    """A 20 cm square of points 1 cm apart at z = 0 (world, m)."""
    xs = np.arange(-0.1, 0.1001, 0.01)
    P = np.array([[x, y, 0.0] for x in xs for y in xs], dtype=np.float32)
    return Cloud(P, np.zeros_like(P, dtype=np.uint8), 0.0, 0)


def click_at(x: float, y: float) -> tuple[Any, Any]:
    """The ray (origin, direction; world) of a click straight down on (x, y)."""
    return (x, y, 1.0), (0.0, 0.0, -1.0)


def test_clicks_during_a_preview_coalesce_into_one_more_of_the_last_list(
    console: tuple[Session, Inbox],
) -> None:
    c, stops = console
    c.c.cloud = grid()
    release, running = threading.Event(), threading.Event()
    previews: list[int] = []  # targets in the list each preview planned

    def preview() -> None:  # stands in for the request to the planner
        previews.append(len(c.targets.items))
        running.set()
        release.wait(30)

    c.do_preview = preview  # type: ignore[method-assign]
    first = threading.Thread(target=c.on_click, args=click_at(0.0, 0.0))
    first.start()
    assert running.wait(10)
    for k in range(1, 4):  # three more clicks while the first preview runs: none waits
        t = threading.Thread(target=c.on_click, args=click_at(0.02 * k, 0.0))
        t.start()
        t.join(5)
        assert not t.is_alive(), "a click waited for the running preview"
    c.panel.stop.click()  # STOP is served while a preview runs
    wait_for(lambda: len(stops.bodies()) == 1, 10.0, "the stop message")
    assert previews == [1] and len(c.targets.items) == 4
    release.set()
    first.join(10)
    assert previews == [1, 4]  # one more preview, of the list after the last click
    picked = np.array([t.p for t in c.targets.items])
    np.testing.assert_allclose(picked[:, 0], [0.0, 0.02, 0.04, 0.06], atol=1e-6)
    assert "click_to_preview" in c.latency
    c.on_click(*click_at(0.08, 0.0))  # idle again: a click previews at once
    assert previews == [1, 4, 5]


def test_each_browser_keeps_its_own_picks_and_any_stop_disarms_all(
    console: tuple[Session, Inbox],
) -> None:
    """Two browsers on one console: a click in one lists and draws the target in that one
    only (its own panel and scene); a STOP pressed in either stops the system and drops the
    other's arming."""
    a, stops = console
    c = a.c
    b = Session(c, panel(), MagicMock()).wire()
    c.sessions[2] = b
    c.cloud = grid()
    a.panel.auto_preview.value = b.panel.auto_preview.value = False
    c._on_click(SimpleNamespace(client_id=1, ray_origin=(0.0, 0.0, 1.0),
                                ray_direction=(0.0, 0.0, -1.0)))  # fmt: skip
    c._on_click(SimpleNamespace(client_id=2, ray_origin=(0.05, 0.0, 1.0),
                                ray_direction=(0.0, 0.0, -1.0)))  # fmt: skip
    c._on_click(SimpleNamespace(client_id=2, ray_origin=(0.05, 0.05, 1.0),
                                ray_direction=(0.0, 0.0, -1.0)))  # fmt: skip
    c._on_click(SimpleNamespace(client_id=7, ray_origin=(0.0, 0.0, 1.0),
                                ray_direction=(0.0, 0.0, -1.0)))  # fmt: skip  # no such browser
    np.testing.assert_allclose([t.p for t in a.targets.items], [[0.0, 0.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose([t.p for t in b.targets.items],
                               [[0.05, 0.0, 0.0], [0.05, 0.05, 0.0]], atol=1e-6)  # fmt: skip
    assert "#1" not in a.panel.targets.content and "#1" in b.panel.targets.content
    # each target marker was drawn in its own browser's scene
    drawn = {
        name: [call.args[0] for call in s.scene.add_icosphere.call_args_list]
        for name, s in (("a", a), ("b", b))
    }
    assert drawn == {"a": ["/targets/0"], "b": ["/targets/0", "/targets/0", "/targets/1"]}
    b.arming.armed = object()  # type: ignore[assignment]  # b armed; a presses STOP
    a.panel.stop.click()
    wait_for(lambda: len(stops.bodies()) == 1, 10.0, "the stop message")
    assert b.arming.armed is None and b.arming.dropped == "STOP"
    c._on_disconnect(SimpleNamespace(client_id=2))  # b's browser left: its session goes
    assert set(c.sessions) == {1}


def test_the_page_shows_a_late_verdict_when_the_drivers_status_carries_it(
    console: tuple[Session, Inbox],
) -> None:
    """After a reply that waited for arm0, the health tick reads arm0's status: a verdict on
    another request changes nothing; the verdict on this one is shown once."""
    from planner.console.live import Stamped
    from schemas.messages import RobotStatus, TrajectoryAck

    s, _ = console
    s.waiting = {"arm0": "req123"}
    s.panel.result.content = "execution: **waiting for arm0**"

    def status(ident: str) -> None:
        ack = TrajectoryAck(id=ident, accepted=True, t=1.0)
        st = RobotStatus(robot="arm0", t=1.0, mode="running", trajectory=ack)
        s.c.live = SimpleNamespace(snapshot=lambda: {"status": {"arm0": Stamped(st, 0.0)}})  # type: ignore[assignment]

    status("other")
    s.watch_verdicts()
    assert s.waiting and "accepted" not in s.panel.result.content
    status("req123")
    s.watch_verdicts()
    s.watch_verdicts()
    assert not s.waiting
    assert s.panel.result.content.count("arm0: **accepted** (late") == 1
