"""``beamrelay console`` and ``up --console``: user mistakes are one line and exit 2; the
listen address checks."""

from __future__ import annotations

import socket

import pytest

from planner.console.address import check_free, check_host, check_port, is_loopback
from planner.errors import InputError
from tests import cli_run
from tests.paths import SCENARIOS

N1 = str(SCENARIOS / "paper_n1.yaml")


def busy_port() -> tuple[socket.socket, int]:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s, s.getsockname()[1]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["console", N1, "--port", "0"], "--port 0: expected a TCP port in 1-65535"),
        (["console", N1, "--port", "70000"], "--port 70000"),
        (["console", N1, "--host", "no such host.invalid"], "--host"),
        (["console", "/nonexistent/s.yaml"], "scenario not found"),
        (["console", N1, "--max-points", "5"], "--max-points 5"),
        (["up", N1, "--console", "--console-port", "0"], "--console-port 0"),
    ],
)
def test_user_mistakes_exit_2_with_one_line(args: list[str], words: str) -> None:
    cli_run.assert_usage_error(cli_run.beamrelay(*args), words)


def test_a_busy_port_is_named() -> None:
    sock, port = busy_port()
    with sock:
        out = cli_run.beamrelay("console", N1, "--port", str(port))
        cli_run.assert_usage_error(out, f"--port {port}: cannot listen on 127.0.0.1:{port}")
        out = cli_run.beamrelay("up", N1, "--console", "--console-port", str(port))
        cli_run.assert_usage_error(out, f"--console-port {port}")


def test_address_checks() -> None:
    assert check_port(8080) == 8080
    for bad in (0, -1, 65536):
        with pytest.raises(InputError):
            check_port(bad)
    assert check_host(" 127.0.0.1 ") == "127.0.0.1"
    assert check_host("localhost") == "localhost"
    for bad in ("", "a b", "tcp/127.0.0.1"):
        with pytest.raises(InputError):
            check_host(bad)
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.10")
    check_free("127.0.0.1", 0)
    with pytest.raises(InputError, match=r"cannot listen on 10\.255\.255\.1"):
        check_free("10.255.255.1", 8080)  # an address this machine does not have


def test_a_weak_token_from_the_environment_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    from planner.service.token import TOKEN_ENV

    for weak in ("short", "a" * 30 + "/"):
        monkeypatch.setenv(TOKEN_ENV, weak)
        out = cli_run.beamrelay("console", N1, "--port", "8099")
        cli_run.assert_usage_error(out, f"{TOKEN_ENV}: expected at least 16 URL-safe")
