"""The planner node's progress watchdog and heartbeat thread on a fake clock: exact beat
times, no burst after a stall, the wedge stop at the allowance."""

from __future__ import annotations

import json
from typing import Any

import pytest

from planner.service.guard import Heartbeat, Progress
from planner.service.heartbeat import HEARTBEAT_RATE
from tests.fake_clock import FakeClock

T0 = 1000.0
PERIOD = 1.0 / HEARTBEAT_RATE


class Beats:
    """A heartbeat on a fake clock, run in the test's thread until ``n`` beats went out."""

    def __init__(self, n: int = 10, stall: dict[int, float] | None = None,
                 progress: Progress | None = None, clock: FakeClock | None = None) -> None:  # fmt: skip
        self.clock = clock or FakeClock(T0)
        self.progress = progress or Progress(clock=self.clock)
        self.times: list[float] = []
        self.bodies: list[dict[str, Any]] = []
        self.wedged: list[str] = []
        self.n, self.stall = n, stall or {}
        self.beat = Heartbeat(self.put, "sess", self.progress, self.wedged.append,
                              clock=self.clock, wait=self.wait)  # fmt: skip

    def put(self, body: bytes) -> None:
        self.times.append(self.clock())
        self.bodies.append(json.loads(body))
        self.clock.advance(self.stall.get(len(self.times), 0.0))  # a publish that blocks

    def wait(self, seconds: float) -> bool:
        self.clock.sleep(seconds)
        return len(self.times) >= self.n

    def run(self) -> Beats:
        self.beat._run()
        return self


def test_beats_every_period_on_the_clock_with_consecutive_seq() -> None:
    b = Beats(n=10).run()
    assert b.times == pytest.approx([T0 + k * PERIOD for k in range(10)], abs=1e-9)
    assert [m["seq"] for m in b.bodies] == list(range(10))
    assert {m["session"] for m in b.bodies} == {"sess"}
    assert all(m["schema"] == "beamrelay.heartbeat/1" for m in b.bodies)
    assert b.wedged == []


def test_a_late_beat_does_not_burst_to_catch_up() -> None:
    """The 3rd publish blocks 45 ms: the next beat goes out at once, then one period apart
    (no catch-up burst of the beats it missed); a short block keeps the schedule."""
    b = Beats(n=8, stall={3: 0.045, 6: 0.004}).run()
    late = T0 + 2 * PERIOD + 0.045
    expected = [T0, T0 + PERIOD, T0 + 2 * PERIOD, late, late + PERIOD, late + 2 * PERIOD,
                late + 3 * PERIOD, late + 4 * PERIOD]  # fmt: skip
    assert b.times == pytest.approx(expected, abs=1e-9)


def test_a_wedged_worker_stops_the_beat_at_its_allowance() -> None:
    clock = FakeClock(T0)
    progress = Progress(timeout=0.5, per_target=0.0, clock=clock)
    b = Beats(n=10_000, progress=progress, clock=clock)
    progress.begin()  # a job starts at T0 and never ends
    b.run()
    assert b.times[-1] == pytest.approx(T0 + 0.5, abs=1e-9)  # busy 0.5 s: still allowed
    assert len(b.times) == 51
    assert b.wedged == ["worker busy on one request for 0.5 s (allowed 0.5 s)"]
    assert clock() == pytest.approx(T0 + 0.51, abs=1e-9)  # the first beat past it is silent


def test_progress_allowance_grows_with_targets_and_ticks_restart_it() -> None:
    clock = FakeClock(T0)
    p = Progress(timeout=0.2, per_target=0.1, clock=clock)
    assert p.overdue() is None
    p.begin()
    p.targets(3)  # 0.2 + 3 * 0.1 s allowed
    clock.advance(0.5)
    assert p.overdue() is None
    clock.advance(1e-6)
    assert p.overdue() == "worker busy on one request for 0.5 s (allowed 0.5 s)"
    p.tick()  # progress: the allowance starts again now
    clock.advance(0.5)
    assert p.overdue() is None
    clock.advance(1e-6)
    assert p.overdue() is not None
    p.end()
    assert p.overdue() is None


def test_the_worker_runs_its_first_task_before_any_job_and_survives_its_failure() -> None:
    import threading

    from planner.service.guard import Job, Worker

    for fails in (False, True):
        order: list[str] = []
        release, done = threading.Event(), threading.Event()

        def first(fails: bool = fails, order: list[str] = order,
                  release: threading.Event = release) -> None:  # fmt: skip
            release.wait(5.0)  # a job submitted meanwhile waits
            order.append("first")
            if fails:
                raise RuntimeError("warm-up failed")

        def respond(job: Any, body: Any, err: Any, order: list[str] = order,
                    done: threading.Event = done) -> None:  # fmt: skip
            order.append(f"reply {body!r} {err!r}")
            done.set()

        w = Worker(lambda b, order=order: (order.append("serve"), b)[1], respond, Progress(),
                   lambda: None, first)  # fmt: skip
        w.start()
        w.submit(Job("query", None, b"x"))
        release.set()
        assert done.wait(5.0)
        w.close(5.0)
        assert order == ["first", "serve", "reply b'x' None"], order


def test_a_wedged_first_task_counts_as_a_wedged_worker() -> None:
    """The warm-up runs under the progress watchdog, as a job does: past its allowance the
    worker is overdue (the heartbeat stops, drivers brake); once it ends, it is not."""
    import threading

    from planner.service.guard import Worker

    clock = FakeClock(T0)
    progress = Progress(timeout=0.5, per_target=0.0, clock=clock)
    seen: list[str | None] = []

    def first() -> None:
        seen.append(progress.overdue())
        clock.advance(0.5 + 1e-6)  # the warm-up hangs past the allowance
        seen.append(progress.overdue())

    ended = threading.Event()
    w = Worker(lambda b: b, lambda *a: None, progress, ended.set, first)
    w.start()
    w.close(5.0)
    assert ended.is_set()
    assert seen == [None, "worker busy on one request for 0.5 s (allowed 0.5 s)"]
    assert progress.overdue() is None
