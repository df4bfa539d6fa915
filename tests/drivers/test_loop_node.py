"""LoopNode: stop ends the loop, then closes the backend, then undeclares in reverse order."""

from __future__ import annotations

import threading
import time

from drivers.loop_node import LoopNode


class _Handle:
    def __init__(self, name: str, log: list[str]) -> None:
        self.name, self.log = name, log

    def undeclare(self) -> None:
        self.log.append(f"undeclare {self.name}")


class _Node(LoopNode):
    def __init__(self) -> None:
        super().__init__()
        self.log: list[str] = []
        self.started = threading.Event()
        self.iterations = 0
        self._handles += [_Handle("sub", self.log), _Handle("token", self.log)]

    def _loop(self) -> None:
        self.started.set()
        while not self._stop.wait(0.001):
            self.iterations += 1
        self.log.append("loop ended")

    def _close(self) -> None:
        assert self._thread is not None
        self.log.append(f"close (loop alive: {self._thread.is_alive()})")


def test_stop_order() -> None:
    node = _Node()
    node._start_loop("test-node")
    assert node.started.wait(5.0)
    node.stop()
    assert node.log == ["loop ended", "close (loop alive: False)", "undeclare token",
                        "undeclare sub"]  # fmt: skip
    assert node._handles == []
    node.wait()  # returns at once: the loop has ended
    assert node._thread is not None and not node._thread.is_alive()


def test_wait_returns_when_the_loop_ends() -> None:
    node = _Node()
    node._start_loop("test-node")
    assert node.started.wait(5.0)
    threading.Timer(0.05, node._stop.set).start()
    node.wait()
    assert node.log == ["loop ended"]  # wait neither closes nor undeclares
    node.stop()
    assert node.log[-2:] == ["undeclare token", "undeclare sub"]


class _Dying(_Node):
    def _loop(self) -> None:
        self.started.set()
        raise RuntimeError("Frame didn't arrive within 5000")


def test_a_dying_loop_records_why(capsys: object) -> None:
    node = _Dying()
    node._start_loop("camera")
    node.wait()
    assert node.failure == "camera loop died: RuntimeError: Frame didn't arrive within 5000"
    node.stop()
    assert node.log[0] == "close (loop alive: False)"  # the device is still released


class _Outliving(_Node):
    """A loop that is still in a slow step when stop() gives up joining it, then meets the
    session stop() closed (zenoh raises "session closed" on the next put)."""

    join_timeout = 0.05

    def _loop(self) -> None:
        self.started.set()
        while not self._stop.is_set():
            time.sleep(0.01)
        time.sleep(0.2)  # the step in progress (a raycast under load) outlives the join
        raise RuntimeError("session closed")


def test_a_loop_that_outlives_stop_is_not_a_failure() -> None:
    node = _Outliving()
    node._start_loop("camera")
    assert node.started.wait(5.0)
    node.stop()  # joins for 0.05 s only
    assert node._thread is not None
    node._thread.join(5.0)
    assert node.failure is None  # exit 0 on SIGTERM, as a clean stop


def test_a_loop_dying_before_any_stop_is_still_a_failure() -> None:
    node = _Dying()
    node._start_loop("camera")
    node.wait()
    assert node.failure is not None and not node._stop.is_set()
