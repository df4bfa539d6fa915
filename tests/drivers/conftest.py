"""Shared fixtures of the driver tests: a private Zenoh bus on a free loopback port."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from planner.service.bus import Keys, open_session


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def keys() -> Keys:
    return Keys("brtest")


@pytest.fixture
def hub(endpoint: str) -> Iterator[Any]:
    """The listening session (plays the planner's side of the bus)."""
    s = open_session(listen=True, endpoint=endpoint)
    yield s
    s.close()


def wait_for(pred: Callable[[], bool], timeout: float = 10.0, what: str = "condition") -> None:
    """Poll ``pred`` until true; fail the test (not hang) after ``timeout`` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")
