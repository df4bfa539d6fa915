"""Only the operator opens the console: its page and socket need the launch's token and, from a
browser, the console's own Origin; when the last browser leaves (closes the tab, or stops
answering its pings), the console publishes STOP. Driven the way a stranger would: plain HTTP
requests and raw websocket handshakes to a real viser server behind the gate."""

from __future__ import annotations

import base64
import os
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from types import SimpleNamespace
from unittest.mock import MagicMock

import pytest

from planner.bus.session import open_session
from planner.console.app import Console
from planner.console.gate import (
    CLOSE_TIMEOUT,
    COOKIE,
    PING_INTERVAL,
    PING_TIMEOUT,
    Gate,
)
from planner.console.operator import Operator
from planner.data import shipped_scenario
from planner.service.client import PlanClient
from planner.service.token import check_token, new_token
from tests.drivers.conftest import free_port, wait_for
from tests.planner.raw_zenoh import Inbox

PREFIX = "gatetest"


def headers(**kw: str) -> dict[str, str]:
    return {k.replace("_", "-"): v for k, v in kw.items()}


def test_the_gate_wants_the_token_and_the_consoles_own_origin() -> None:
    gate = Gate.for_address("127.0.0.1", 8080, "a" * 22)
    ok = f"{COOKIE}={'a' * 22}"
    ws = {"Upgrade": "websocket"}
    assert gate.refusal("/?token=" + "a" * 22, {}) is None
    assert gate.refusal("/assets/x.js", {"Cookie": f"other=1; {ok}"}) is None
    assert gate.refusal("/", {**ws, "Cookie": ok, "Origin": "http://localhost:8080"}) is None
    assert gate.refusal("/", {**ws, "Cookie": ok}) is None  # not a browser: the token suffices
    for path, hdrs in [
        ("/", {}),
        ("/?token=" + "a" * 21, {}),  # one character short
        ("/?token=", {"Cookie": f"{COOKIE}="}),
        ("/", {**ws, "Origin": "http://localhost:8080"}),  # the right origin, no token
    ]:
        assert gate.refusal(path, hdrs)[0] == 401, (path, hdrs)  # type: ignore[index]
    for origin in ("http://evil.example", "http://127.0.0.1:8081", "https://127.0.0.1:8080",
                   "null"):  # fmt: skip
        refused = gate.refusal("/", {**ws, "Cookie": ok, "Origin": origin})
        assert refused is not None and refused[0] == 403, origin
    # not on loopback: only the console's own address
    lan = Gate.for_address("10.1.2.3", 9000, "b" * 22)
    assert lan.origins == frozenset({"http://10.1.2.3:9000"})


def test_tokens_are_fresh_and_weak_ones_are_refused() -> None:
    assert len({new_token() for _ in range(100)}) == 100
    assert check_token(new_token())
    for bad in ("", "short", "x" * 15, "a" * 20 + " ", "a" * 20 + "/"):
        with pytest.raises(ValueError, match="16 URL-safe"):
            check_token(bad)


@pytest.fixture
def console() -> Iterator[tuple[Console, Inbox, int]]:
    """A console's viser server behind its gate on a free port, its operator on a private
    bus; an inbox of ``<prefix>/stop`` on that bus."""
    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    hub = open_session(listen=True, endpoint=endpoint)
    c = Console(shipped_scenario("s_curve.yaml"), port=port, endpoint=endpoint, prefix=PREFIX)
    c.client = PlanClient(endpoint=endpoint, prefix=PREFIX)
    c.operator = Operator(c.client)
    c.server = c.serve()
    stops = Inbox(hub, f"{PREFIX}/stop")
    yield c, stops, port
    c.server.stop()
    stops.close()
    c.client.close()
    hub.close()


def get(url: str, cookie: str | None = None) -> tuple[int, dict[str, str], bytes]:
    req = urllib.request.Request(url, headers={"Cookie": cookie} if cookie else {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, dict(exc.headers), exc.read()


def test_the_page_is_served_only_with_the_token(console: tuple[Console, Inbox, int]) -> None:
    c, _, port = console
    base = f"http://127.0.0.1:{port}/"
    status, _, body = get(base)
    assert status == 401 and b"needs its token" in body and b"<html" not in body.lower()
    assert get(base + "?token=" + "x" * 22)[0] == 401
    assert get(base + "assets/../index.html")[0] == 401  # nothing passes without the token
    assert c.url == f"{base}?token={c.gate.token}"
    status, hdrs, body = get(c.url)
    assert status == 200 and b"<html" in body.lower()
    cookie = hdrs["Set-Cookie"]
    assert cookie.startswith(f"{COOKIE}={c.gate.token};")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    # the page's own requests carry the cookie
    assert get(base, cookie=f"{COOKIE}={c.gate.token}")[0] == 200


def test_the_page_carries_the_space_bar_stop_uncompressed(
    console: tuple[Console, Inbox, int],
) -> None:
    """The served page is viser's page with the space bar's handler added once, before its
    last ``</body>``, with a Content-Length that is the body's; a browser offering gzip gets
    it uncompressed too (viser's app is compressed inside it); a refused request gets no
    page and no script."""
    from pathlib import Path

    import viser

    from planner.console.hotkeys import SCRIPT

    c, _, port = console
    original = (Path(viser.__file__).parent / "client" / "build" / "index.html").read_bytes()
    status, hdrs, body = get(c.url)
    req = urllib.request.Request(c.url, headers={"Accept-Encoding": "gzip, deflate, br"})
    with urllib.request.urlopen(req, timeout=10) as r:
        offered_headers, offered = dict(r.headers), r.read()
    assert status == 200 and int(hdrs["Content-Length"]) == len(body)
    assert offered_headers.get("Content-Encoding", "identity") == "identity"
    assert int(offered_headers["Content-Length"]) == len(offered)
    for html in (body, offered):
        at = html.rfind(b"</body>")
        assert html.count(SCRIPT) == 1 and html.index(SCRIPT) + len(SCRIPT) == at
        assert html.replace(SCRIPT, b"") == original
    status, _, refused = get(f"http://127.0.0.1:{port}/")
    assert status == 401 and SCRIPT not in refused


def camera_message() -> bytes:
    """A viewer-camera message: viser counts a socket as a client after its first one."""
    import msgspec
    from viser._messages import ViewerCameraMessage

    m = ViewerCameraMessage((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 1.0, 0.01, 100.0, 480, 640,
                            (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))  # fmt: skip
    return bytes(msgspec.msgpack.encode(m.as_serializable_dict()))


def masked_frame(payload: bytes) -> bytes:
    """One binary websocket frame as a client sends it (RFC 6455: masked)."""
    mask, n = os.urandom(4), len(payload)
    size = bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + n.to_bytes(2, "big")
    return bytes([0x82]) + size + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def handshake(port: int, path: str = "/", **extra: str) -> tuple[socket.socket, bytes]:
    """A raw websocket handshake (viser's subprotocol); the socket and the status line. When
    it is accepted, the socket sends one camera message (so viser counts it) and then
    nothing: it never reads, so never answers a ping."""
    import viser

    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    key = base64.b64encode(os.urandom(16)).decode()
    lines = [f"GET {path} HTTP/1.1", f"Host: 127.0.0.1:{port}", "Upgrade: websocket",
             "Connection: Upgrade", f"Sec-WebSocket-Key: {key}", "Sec-WebSocket-Version: 13",
             f"Sec-WebSocket-Protocol: viser-v{viser.__version__}",
             *(f"{k}: {v}" for k, v in headers(**extra).items())]  # fmt: skip
    s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
    reply = b""
    while b"\r\n\r\n" not in reply:
        chunk = s.recv(4096)
        if not chunk:
            break
        reply += chunk
    line = reply.split(b"\r\n", 1)[0]
    if b" 101 " in line:
        s.sendall(masked_frame(camera_message()))
    return s, line


def test_sockets_without_the_token_or_from_a_foreign_origin_are_refused(
    console: tuple[Console, Inbox, int],
) -> None:
    c, stops, port = console
    own, cookie = f"http://127.0.0.1:{port}", f"{COOKIE}={c.gate.token}"
    for path, extra, status in [
        ("/", {"Origin": own}, b"401"),
        ("/?token=" + "y" * 22, {"Origin": own}, b"401"),
        ("/", {"Origin": "http://evil.example", "Cookie": cookie}, b"403"),
        ("/", {"Origin": f"http://127.0.0.1:{port + 1}", "Cookie": cookie}, b"403"),
    ]:
        s, line = handshake(port, path, **extra)
        s.close()
        assert status in line, (path, extra, line)
    assert not c.server.get_clients()
    s, line = handshake(port, "/", Origin=own, Cookie=cookie)
    assert b" 101 " in line, line
    wait_for(lambda: len(c.server.get_clients()) == 1, 10.0, "the client registered")
    s.close()
    wait_for(lambda: len(stops.bodies()) == 1, 10.0, "STOP once the only browser left")


def test_a_silent_browser_is_dropped_and_stop_waits_for_the_last(
    console: tuple[Console, Inbox, int],
) -> None:
    import viser
    from websockets.sync.client import connect

    c, stops, port = console
    own, cookie = f"http://localhost:{port}", f"{COOKIE}={c.gate.token}"
    # a browser that answers its pings (websockets' client does, on its own thread)
    b = connect(f"ws://127.0.0.1:{port}/?token={c.gate.token}", origin=own,  # type: ignore[arg-type]
                subprotocols=[f"viser-v{viser.__version__}"])  # type: ignore[list-item]  # fmt: skip
    b.send(camera_message())
    wait_for(lambda: len(c.server.get_clients()) == 1, 10.0, "the first client registered")
    # one that never reads, so never answers a ping
    t0 = time.monotonic()
    a, line = handshake(port, "/", Origin=own, Cookie=cookie)
    assert b" 101 " in line
    wait_for(lambda: len(c.server.get_clients()) == 2, 10.0, "two clients registered")
    wait_for(lambda: len(c.server.get_clients()) == 1, 20.0, "the silent client dropped")
    silent = time.monotonic() - t0
    assert silent >= PING_TIMEOUT - 0.05, silent  # dropped by the ping, not by a close
    # and promptly: without the short close timeout it counted 10 s more (measured 11.5 s)
    assert silent < PING_INTERVAL + PING_TIMEOUT + CLOSE_TIMEOUT + 5.0, silent
    time.sleep(0.3)
    assert stops.bodies() == []  # the other still watches
    b.close()
    wait_for(lambda: len(stops.bodies()) == 1, 10.0, "STOP once the last browser left")
    msg = stops.bodies()[0]
    assert (msg["source"], msg["reason"]) == (
        "console", "no operator console is open (the last browser left)")  # fmt: skip
    assert c.unwatched_stops == 1
    a.close()
    print(f"\na silent browser was dropped after {silent:.2f} s (pings every {PING_INTERVAL} s, "
          f"{PING_TIMEOUT} s to answer)")  # fmt: skip


def test_no_stop_while_the_console_closes() -> None:
    c = Console(shipped_scenario("s_curve.yaml"))
    c.server, c.operator = MagicMock(), MagicMock()
    c.server.get_clients.return_value = {}
    c._stop.set()
    c._on_disconnect(SimpleNamespace(client_id=1))
    c.operator.stop.assert_not_called()
