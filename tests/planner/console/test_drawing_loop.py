"""The drawing thread's cloud pacing: with the camera at 15 Hz and the drawing tick at 30 Hz
(each tick taking some work time), the browser gets cloud frames at the console's rate
(``CLOUD_RATE``, the smaller of it and the camera's), never faster; run on a simulated clock
through :meth:`DrawLoop.cloud` itself."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from planner.console import drawing_loop
from planner.console.cloud import Cloud
from planner.console.drawing_loop import CLOUD_RATE, DrawLoop, next_due

CAMERA_HZ = 15.0  # the simulated camera's frame rate
TICK_S = 1.0 / 30.0  # the drawing loop's period (DRAW_RATE)


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Live:
    """The newest camera frame at the simulated time: frame k arrives at k / CAMERA_HZ."""

    def __init__(self, clock: Clock) -> None:
        self.clock, self.rejected = clock, 0

    def take_points(self, since_seq: int) -> tuple[int, tuple[bytes, bytes] | None]:
        seq = int(self.clock() * CAMERA_HZ)
        return seq, (None if seq == since_seq else (b"", b""))


def console(clock: Clock) -> Any:
    cloud = Cloud(np.zeros((4, 3), np.float32), np.zeros((4, 3), np.uint8), 0.0, 0)
    scene = SimpleNamespace(add_point_cloud=lambda *a, **k: SimpleNamespace(points=cloud.points))
    return SimpleNamespace(live=Live(clock), new_cloud=lambda *a: cloud, cloud=None,
                           server=SimpleNamespace(scene=scene), cloud_frames=0)  # fmt: skip


@pytest.mark.parametrize("work_s", [0.0, 0.004, 0.012])
def test_cloud_frames_go_at_the_console_rate(
    monkeypatch: pytest.MonkeyPatch, work_s: float
) -> None:
    clock = Clock()
    monkeypatch.setattr(drawing_loop.time, "monotonic", clock)
    c = console(clock)
    loop = DrawLoop(c)
    seconds = 30.0
    while clock.t < seconds:
        loop.cloud(None)
        clock.t += TICK_S + work_s  # the tick's wait, then its work
    expected = min(CLOUD_RATE, CAMERA_HZ)
    assert expected - 0.1 <= c.cloud_frames / seconds <= expected + 1.0 / seconds


def test_the_next_frame_is_due_a_period_after_the_last_was_due() -> None:
    period = 0.1
    assert next_due(1.0, 1.03, period) == pytest.approx(1.1)  # sent late: no drift
    assert next_due(1.0, 1.0, period) == pytest.approx(1.1)
    # after a pause (no camera frame for a while) one frame may follow at once, not a burst
    assert next_due(1.0, 5.0, period) == pytest.approx(5.0)
    assert next_due(5.0, 5.0, period) == pytest.approx(5.1)
