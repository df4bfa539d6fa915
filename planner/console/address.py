"""Where the console's web server listens: host and port checks (light, no heavy imports).

The page opens only with its launch's token (:mod:`planner.console.gate`), but it is plain
HTTP: anyone who sees the URL can move the robots. It therefore listens on loopback
(127.0.0.1) unless told otherwise, and says so loudly when it is not.
"""

from __future__ import annotations

import ipaddress
import socket

from planner.errors import InputError

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080


def check_port(port: int, option: str = "--port") -> int:
    """``port`` if in 1-65535, else an InputError naming ``option``."""
    if not 1 <= port <= 65535:
        raise InputError(f"{option} {port}: expected a TCP port in 1-65535")
    return port


def check_host(host: str, option: str = "--host") -> str:
    """``host`` if it is an IP address or a name that resolves, else an InputError."""
    text = host.strip()
    if not text or any(c.isspace() for c in text) or "/" in text:
        raise InputError(f"{option} {host!r}: expected an IP address or host name")
    try:
        ipaddress.ip_address(text)
        return text
    except ValueError:
        pass
    try:
        socket.getaddrinfo(text, None)
    except (socket.gaierror, UnicodeError):
        raise InputError(f"{option} {host!r}: cannot resolve this host name") from None
    return text


def is_loopback(host: str) -> bool:
    """True when ``host`` (address or name) only resolves to loopback addresses."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except (socket.gaierror, UnicodeError):
        return False
    return bool(infos) and all(ipaddress.ip_address(i[4][0]).is_loopback for i in infos)


def check_free(host: str, port: int, option: str = "--port") -> None:
    """InputError naming ``option`` when ``host:port`` cannot be bound (in use, or an
    address this machine does not have)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            raise InputError(
                f"{option} {port}: cannot listen on {host}:{port}: {exc.strerror}"
            ) from None
