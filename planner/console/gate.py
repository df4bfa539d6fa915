"""Who may open the operator console: a per-launch token and an Origin allow-list.

The console moves robots and switches the laser, so a page and its websocket are served only
to whoever holds the token the launching command printed (in the URL, ``?token=...``). The
first page load with the token sets it as an ``HttpOnly; SameSite=Strict`` cookie, which the
page's own requests (scripts, the websocket) carry from then on. A websocket handshake passes
only with the token and, when it comes from a browser (it has an ``Origin``), only from an
allowed origin: the console's own address. Any other web page open in the operator's browser
can neither read the page (no token) nor open the socket (a foreign Origin, and no cookie).

viser serves its page and socket from one ``websockets`` server and has no hook for this;
:func:`guarded_serve` wraps the ``process_request`` it passes to ``websockets.asyncio.server
.serve`` while the viser server starts (and sets the keep-alive pings, so a browser that stops
answering for :data:`PING_TIMEOUT` is dropped). The page goes out uncompressed, with the
space bar's script (:func:`planner.console.hotkeys.with_hotkeys`).
"""

from __future__ import annotations

import contextlib
import hmac
import http
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, urlsplit

from planner.console.address import is_loopback
from planner.console.hotkeys import with_hotkeys
from planner.service.token import check_token, console_url

COOKIE = "beamrelay_console"
#: s between websocket pings to each browser, and the wait for its answer before the
#: connection counts as lost (the console then stops the system if no browser is left)
PING_INTERVAL = 0.5
PING_TIMEOUT = 1.0
#: s a closing socket waits for the browser's close frame (websockets' default, 10 s, kept a
#: silent browser counted as present for 10 s more)
CLOSE_TIMEOUT = 0.25
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")


@dataclass(frozen=True)
class Gate:
    """The token and the origins a browser may open the console's socket from."""

    token: str
    origins: frozenset[str]

    @classmethod
    def for_address(cls, host: str, port: int, token: str) -> Gate:
        """Origins of the console's own address; on loopback, every loopback name of it."""
        names = {host, *LOOPBACK_NAMES} if is_loopback(host) else {host}
        names = {f"[{n}]" if ":" in n and not n.startswith("[") else n for n in names}
        return cls(check_token(token), frozenset(f"http://{n}:{port}" for n in names))

    def url(self, host: str, port: int) -> str:
        return console_url(host, port, self.token)

    def _holds(self, path: str, cookie: str | None) -> bool:
        offered = [*query_tokens(path), *cookie_tokens(cookie)]
        return any(hmac.compare_digest(t.encode(), self.token.encode()) for t in offered)

    def refusal(self, path: str, headers: Any) -> tuple[http.HTTPStatus, str] | None:
        """None when the request may pass, else the status and the one-line reason."""
        origin = headers.get("Origin")
        socket = headers.get("Upgrade", "").lower() == "websocket"
        if socket and origin is not None and origin not in self.origins:
            return http.HTTPStatus.FORBIDDEN, f"origin {origin} may not open this console"
        if not self._holds(path, headers.get("Cookie")):
            return (
                http.HTTPStatus.UNAUTHORIZED,
                "this console needs its token: open the URL its command printed",
            )
        return None

    def cookie(self) -> str:
        return f"{COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/"


def query_tokens(path: str) -> list[str]:
    return parse_qs(urlsplit(path).query).get("token", [])


def cookie_tokens(cookie: str | None) -> list[str]:
    out = []
    for part in (cookie or "").split(";"):
        name, _, value = part.strip().partition("=")
        if name == COOKIE:
            out.append(value)
    return out


def gated(gate: Gate, inner: Callable[..., Any] | None) -> Callable[..., Any]:
    """A ``process_request`` refusing what :meth:`Gate.refusal` refuses, else ``inner``'s
    answer (with the cookie set when the token came in the URL)."""

    def process_request(connection: Any, request: Any) -> Any:
        refused = gate.refusal(request.path, request.headers)
        if refused is not None:
            status, reason = refused
            return connection.respond(status, reason + "\n")
        response = inner(connection, request) if inner is not None else None
        if response is not None and query_tokens(request.path):
            response.headers["Set-Cookie"] = gate.cookie()
            response.headers["Cache-Control"] = "no-store"
        return response

    return process_request


@contextlib.contextmanager
def guarded_serve(gate: Gate) -> Iterator[None]:
    """While inside, every ``websockets.asyncio.server.serve`` (viser's server start) passes
    its requests through ``gate``, pings its clients every :data:`PING_INTERVAL` and drops one
    that does not answer within :data:`PING_TIMEOUT` (+ :data:`CLOSE_TIMEOUT`); the page it
    serves carries the space bar's STOP (:mod:`planner.console.hotkeys`)."""
    import websockets.asyncio.server as ws_server

    serve = ws_server.serve

    def guarded(*args: Any, **kwargs: Any) -> Any:
        kwargs["process_request"] = gated(gate, with_hotkeys(kwargs.get("process_request")))
        kwargs["ping_interval"], kwargs["ping_timeout"] = PING_INTERVAL, PING_TIMEOUT
        kwargs["close_timeout"] = CLOSE_TIMEOUT
        return serve(*args, **kwargs)

    ws_server.serve = guarded  # type: ignore[assignment,misc]
    try:
        yield
    finally:
        ws_server.serve = serve  # type: ignore[misc]
