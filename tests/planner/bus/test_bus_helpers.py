"""The subscriber helpers of :mod:`planner.bus.session` on hand-made samples: the liveliness
set and decoding that logs a bad body instead of raising."""

from __future__ import annotations

import json
import logging
import threading
from types import SimpleNamespace
from typing import Any

import pytest
import zenoh

from planner.bus.session import decode_sample, update_alive
from schemas.messages import LaserState


class Body:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


def token(key: str, kind: Any) -> Any:
    return SimpleNamespace(key_expr=key, kind=kind)


def test_liveliness_samples_add_and_remove_the_node_named_by_the_key() -> None:
    alive: set[str] = set()
    lock = threading.Lock()
    assert update_alive(alive, lock, token("p/alive/arm0", zenoh.SampleKind.PUT)) == ("arm0", True)
    assert update_alive(alive, lock, token("p/alive/planner", zenoh.SampleKind.PUT))[1]
    assert alive == {"arm0", "planner"}
    gone = update_alive(alive, lock, token("p/alive/arm0", zenoh.SampleKind.DELETE))
    assert gone == ("arm0", False) and alive == {"planner"}
    # a node that was never up going away changes nothing
    assert update_alive(alive, lock, token("p/alive/cam", zenoh.SampleKind.DELETE))[1] is False
    assert alive == {"planner"}


@pytest.mark.parametrize(
    "data",
    [
        b"\xff\xfe",
        b"[]",
        b'{"schema": "beamrelay.laser/1", "robot": "arm0", "t": 1.0, "on": "maybe"}',
    ],
)
def test_a_bad_body_is_logged_and_dropped(data: bytes, caplog: pytest.LogCaptureFixture) -> None:
    log = logging.getLogger("test.bus")
    with caplog.at_level(logging.WARNING, "test.bus"):
        assert decode_sample(SimpleNamespace(payload=Body(data)), LaserState, log, "laser") is None
    assert len(caplog.records) == 1 and caplog.records[0].getMessage().startswith("bad laser: ")


def test_a_good_body_is_decoded() -> None:
    body = json.dumps(
        {"schema": "beamrelay.laser/1", "robot": "arm0", "t": 2.5, "on": True}
    ).encode()
    msg = decode_sample(SimpleNamespace(payload=Body(body)), LaserState, logging.getLogger(), "x")
    assert msg is not None and msg.t == 2.5 and msg.on is True
