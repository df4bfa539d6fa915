"""Hostile payloads against the planner node, sent by an outside client (plain zenoh).

Whatever arrives on ``<prefix>/plan`` or ``<prefix>/targets``, the node answers with an
error naming the field and keeps serving; bodies that would crash the reply itself (lone
surrogates, 10^5-digit integers) included. ``decode``/``error_body`` are also checked
against generated garbage (hypothesis).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.bus.session import Keys, decode, open_session
from planner.errors import InputError
from planner.model.system import System
from planner.service.node import (
    PlannerNode,
    RequestHandler,
    error_body,
    make_plan_fn,
    request_id_of,
)
from schemas.messages import ErrorReply, TargetRequest
from tests.drivers.conftest import free_port, wait_for
from tests.planner.raw_zenoh import Inbox, ask, raw_session
from tests.planner.service.test_node import reachable_targets, system_with_camera

PREFIX = "hostile"
HEAD = b'{"schema":"beamrelay.request/1","id":"h1",'


def req(points: bytes, extra: bytes = b"") -> bytes:
    return HEAD + b'"points":' + points + extra + b"}"


def garbage(n: int, seed: int) -> bytes:
    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


# (body, field of the error, words in the error text)
CORPUS: list[tuple[str, bytes, str, str]] = [
    ("surrogate id", HEAD.replace(b'"h1"', b'"\\ud800x"') + b'"points":[[0.5,0,0.3]]}', "id",
     "surrogate"),
    ("surrogate low id", HEAD.replace(b'"h1"', b'"x\\uDFFF"') + b'"points":[[0.5,0,0.3]]}', "id",
     "surrogate"),
    ("surrogate frame", req(b"[[0.5,0,0.3]]", b',"frame":"\\udc00"'), "frame", "surrogate"),
    ("surrogate key", req(b"[[0.5,0,0.3]]", b',"\\ud800":1'), "\\ud800", "surrogate"),
    ("5000-digit int", req(b"[[" + b"9" * 5000 + b",0,0]]"), "points[0][0]", "5000-digit"),
    ("1e5-digit int", req(b"[[0,-" + b"7" * 100_000 + b",0]]"), "points[0][1]", "100000-digit"),
    ("1e5-digit body", b"9" * 100_000, "body", "100000-digit"),
    ("1e5-digit float", req(b"[[0,0,1" + b"0" * 100_000 + b".5]]"), "points[0][2]", "finite"),
    ("1e99999", req(b"[[1e99999,0,0]]"), "points[0][0]", "finite"),
    ("NaN", req(b"[[NaN,0,0]]"), "points[0][0]", "finite"),
    ("Infinity", req(b"[[0,Infinity,0]]"), "points[0][1]", "finite"),
    ("-Infinity", req(b"[[0,0,-Infinity]]"), "points[0][2]", "finite"),
    ("1e308", req(b"[[1e308,0,0]]"), "points[0][0]", "100 m"),
    ("-1e308", req(b"[[0.5,0,0.3],[0,-1e308,0]]"), "points[1][1]", "100 m"),
    ("101 m", req(b"[[101,0,0]]"), "points[0][0]", "<= 100 m, got 101 m"),
    ("huge normal", req(b"[[0.5,0,0.3]]", b',"normals":[[1e200,0,0]]'), "normals[0][0]", "1e+06"),
    ("zero normal", req(b"[[0.5,0,0.3]]", b',"normals":[[0,0,0]]'), "normals[0]", "zero"),
    ("deep array", b"[" * 100_000 + b"]" * 100_000, "body", "nested too deeply"),
    ("deep in points", req(b"[" * 100_000 + b"]" * 100_000), "body", "nested too deeply"),
    ("deep object", b'{"a":' * 100_000 + b"1" + b"}" * 100_000, "body", "100000 objects"),
    ("900 deep", req(b"[" + b"[" * 900 + b"]" * 900 + b"]"), "points[0]", "expected 3"),
    ("id number", HEAD.replace(b'"h1"', b"5") + b'"points":[[0.5,0,0.3]]}', "id", "string"),
    ("points string", req(b'"abc"'), "points", "list"),
    ("points mapping", req(b"{}"), "points", "list"),
    ("point strings", req(b'[["0.5","0","0.3"]]'), "points[0][0]", "number"),
    ("point bool", req(b"[[true,0,0]]"), "points[0][0]", "number"),
    ("execute string", req(b"[[0.5,0,0.3]]", b',"execute":"yes"'), "execute", "true or false"),
    ("schema number", b'{"schema":1,"id":"a","points":[[0.5,0,0.3]]}', "schema", "expected"),
    ("unknown key", req(b"[[0.5,0,0.3]]", b',"robots":["x"]'), "robots", "unknown key"),
    ("huge id", HEAD.replace(b'"h1"', b'"' + b"i" * 3_000_000 + b'"') + b'"points":[[0,0,0]]}',
     "id", "at most 256"),
    ("huge frame", req(b"[[0.5,0,0.3]]", b',"frame":"' + b"w" * 3_000_000 + b'"'), "frame",
     "expected"),
    ("too many points", req(b"[" + b",".join([b"[0.5,0,0.3]"] * 10_001) + b"]"), "points",
     "at most 10000"),
    ("binary garbage", garbage(154, 1), "body", "invalid JSON"),
    ("binary 1 MB", garbage(1_000_000, 2), "body", "invalid JSON"),
    ("utf-16 body", '{"schema":"beamrelay.request/1"}'.encode("utf-16"), "body", "UTF-8"),
    ("invalid utf-8 in string", req(b"[[0.5,0,0.3]]", b',"frame":"\xed\xa0\x80"'), "body",
     "UTF-8"),
    ("empty body", b"", "body", "invalid JSON"),
    ("null", b"null", "body", "mapping"),
    ("list", b"[1,2,3]", "body", "mapping"),
    ("string", b'"\\ud800"', "body", "surrogate"),
    ("true", b"true", "body", "mapping"),
    ("truncated", req(b"[[0.5,0,0.3]]")[:-5], "body", "invalid JSON"),
    ("path of one", req(b"[[0.5,0,0.3]]", b',"mode":"path"'), "points", "at least 2"),
    ("zero-length path", req(b"[[0.5,0,0.3],[0.5,0,0.3]]", b',"mode":"path"'), "points",
     "zero length"),
    ("opposite path normals", req(b"[[0.5,0,0.3],[0.52,0,0.3]]",
                                  b',"mode":"path","normals":[[0,0,1],[0,0,-1]]'),
     "normals", "opposite"),
    ("path too long", req(b"[[0,0,0],[19,0,0]]", b',"mode":"path"'), "points", "samples"),
    ("4 MB of lists", req(b"[" + b"[]," * 1_300_000 + b"[]]"), "body", "1300002 lists"),
    ("4 MB of objects", req(b"[" + b"{}," * 1_300_000 + b"{}]"), "body", "objects"),
    ("4 MB of strings", req(b"[" + b'"",' * 1_300_000 + b'""]'), "body", "quotes"),
    ("4 MB of nulls", req(b"[" + b"null," * 800_000 + b"null]"), "body", "null literals"),
]  # fmt: skip


@pytest.fixture(scope="module")
def system() -> System:
    return system_with_camera()


@pytest.fixture(scope="module")
def bus(system: System) -> Iterator[tuple[PlannerNode, Any]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_session(listen=True, endpoint=endpoint)
    node = PlannerNode(RequestHandler(system, make_plan_fn(system, {})), hub, Keys(PREFIX))
    node.start()
    client = raw_session(endpoint)
    try:
        wait_for(lambda: ask_ok(client, system), 20.0, "planner answering")
        yield node, client
    finally:
        client.close()
        node.close()
        hub.close()


def ask_ok(client: Any, system: System) -> bool:
    """A good request gets a plan whose solution puts the beam on the target."""
    from planner.beam.graph import BeamModel

    p = reachable_targets(system, 1, seed=7)[0]
    body = json.dumps({"schema": "beamrelay.request/1", "id": "good", "points": [p.tolist()]})
    ok, reply = ask(client, f"{PREFIX}/plan", body.encode())
    plan = json.loads(reply)
    assert ok, plan
    assert plan["id"] == "good" and plan["solutions"][0]["status"] == "ok"
    tr = BeamModel(system).trace(system.stack_q(plan["solutions"][0]["q"]), p)
    return bool(tr.valid and tr.error < 1e-8)


def check_error(raw: bytes, field: str, words: str) -> dict[str, Any]:
    reply = raw.decode("utf-8")  # strict: the reply is valid UTF-8
    err = json.loads(reply)
    ErrorReply.model_validate(err)
    assert err["field"] == field, err
    assert words.lower() in err["error"].lower(), err
    assert len(raw) < 5000
    return dict(err)


@pytest.mark.parametrize(("body", "field", "words"), [c[1:] for c in CORPUS],
                         ids=[c[0] for c in CORPUS])  # fmt: skip
def test_poisoned_query_gets_error_naming_the_field(
    bus: tuple[PlannerNode, Any], system: System, body: bytes, field: str, words: str
) -> None:
    node, client = bus
    ok, reply = ask(client, f"{PREFIX}/plan", body)
    assert not ok
    check_error(reply, field, words)
    assert node._worker.is_alive() and node.failed is None
    assert ask_ok(client, system)


def test_poisoned_topic_gets_error_on_plans(bus: tuple[PlannerNode, Any], system: System) -> None:
    node, client = bus
    inbox = Inbox(client, f"{PREFIX}/plans")
    try:
        wait_for(lambda: bool(client.put(f"{PREFIX}/targets", b"") or inbox.bodies()), 10.0,
                 "the subscription to reach the node")  # fmt: skip
        n0 = -1
        while n0 != len(inbox.bodies()):  # let the answers to the probes drain
            n0 = len(inbox.bodies())
            time.sleep(0.5)
        for _, body, _, _ in CORPUS:
            client.put(f"{PREFIX}/targets", body)
        p = reachable_targets(system, 1, seed=8)[0]
        good = {"schema": "beamrelay.request/1", "id": "good-topic", "points": [p.tolist()]}
        client.put(f"{PREFIX}/targets", json.dumps(good).encode())
        wait_for(lambda: len(inbox.bodies()) >= n0 + len(CORPUS) + 1, 60.0, "every answer")
    finally:
        inbox.close()
    got = inbox.bodies()[n0:]
    for (name, _, field, words), err in zip(CORPUS, got, strict=False):
        assert isinstance(err, dict) and err["schema"] == "beamrelay.error/1", name
        assert err["field"] == field and words.lower() in err["error"].lower(), (name, err)
    assert got[-1]["id"] == "good-topic" and got[-1]["solutions"][0]["status"] == "ok"
    assert node._worker.is_alive() and node.failed is None


# --- generated garbage, without the bus ------------------------------------------------------
LONE_SURROGATES = st.sampled_from(["\ud800", "\udbff", "\udc00", "\udfff"])
json_text = st.text(st.characters(codec=None, exclude_categories=()) | LONE_SURROGATES,
                    max_size=20)  # fmt: skip
huge_ints = st.sampled_from([10**400, -(10**1000), 10**4000])
json_values = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | huge_ints | json_text,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(json_text, inner, max_size=4),
    max_leaves=30,
)


def check_never_crashes(body: bytes) -> None:
    try:
        msg = decode(body, TargetRequest)
    except InputError as exc:
        assert exc.where, exc
        raw = error_body(exc, request_id_of(body))
        err = json.loads(raw.decode("utf-8"))
        ErrorReply.model_validate(err)
        assert err["field"]
    else:
        json.dumps(msg.model_dump(by_alias=True), ensure_ascii=False).encode("utf-8")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_decode_of_random_bytes_is_a_request_or_a_located_error(body: bytes) -> None:
    check_never_crashes(body)


@settings(max_examples=300, deadline=None)
@given(json_values, st.sampled_from(["id", "frame", "points", "normals", "mode", "x"]))
def test_decode_of_random_json_is_a_request_or_a_located_error(value: Any, key: str) -> None:
    doc = {"schema": "beamrelay.request/1", "id": "g", "points": [[0.5, 0.0, 0.3]], key: value}
    check_never_crashes(json.dumps(doc, allow_nan=True).encode())  # ascii: \\ud800 escapes
    check_never_crashes(json.dumps(value, allow_nan=True).encode())


def test_error_body_survives_anything() -> None:
    class UnprintableError(Exception):
        def __str__(self) -> str:
            raise RuntimeError("no text")

    for exc, rid in [
        (InputError("bad \ud800 value", "x\udfff"), "a\ud800"),
        (RuntimeError("x" * 1_000_000), "i" * 10_000),
        (UnprintableError(), None),
    ]:
        err = json.loads(error_body(exc, rid).decode("utf-8"))
        ErrorReply.model_validate(err)
        assert len(err["error"]) <= 2000
    assert request_id_of(b'{"id": "\\ud800"}') == "\\ud800"
    assert request_id_of(b'{"id": 1, "x": ' + b"9" * 5000 + b"}") is None
    assert request_id_of(b"[" * 100_000) is None
