"""The operator console's per-launch token (light: no heavy imports). ``beamrelay up`` makes
one per launch and hands it to its console child in the environment (argv is readable by
every local user; a process's environment only by its owner); the console checks it in
:mod:`planner.console.gate`."""

from __future__ import annotations

import secrets

#: environment variable through which ``beamrelay up`` hands its token to the console child
TOKEN_ENV = "BEAMRELAY_CONSOLE_TOKEN"


def new_token() -> str:
    """A fresh random token (128 bits, URL-safe)."""
    return secrets.token_urlsafe(16)


def check_token(token: str) -> str:
    """``token`` if it is long enough and URL-safe, else ValueError (a short or odd token from
    the environment is refused rather than silently weakened)."""
    if len(token) < 16 or not all(c.isalnum() or c in "-_" for c in token):
        raise ValueError(f"{TOKEN_ENV}: expected at least 16 URL-safe characters")
    return token


def console_url(host: str, port: int, token: str) -> str:
    """The console page's address with its token: the only way in."""
    return f"http://{host}:{port}/?token={token}"
