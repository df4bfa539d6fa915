"""``beamrelay console`` and ``up --console``: user mistakes are one line and exit 2; the
listen address checks."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from planner.console.address import check_free, check_host, check_port, is_loopback
from planner.errors import InputError
from tests.paths import SCENARIOS

N1 = str(SCENARIOS / "paper_n1.yaml")


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *args], capture_output=True,
                          text=True, timeout=180)  # fmt: skip


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
    out = run(*args)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], out.stderr


def test_a_busy_port_is_named() -> None:
    sock, port = busy_port()
    with sock:
        out = run("console", N1, "--port", str(port))
        assert out.returncode == 2
        assert f"--port {port}: cannot listen on 127.0.0.1:{port}" in out.stderr
        out = run("up", N1, "--console", "--console-port", str(port))
        assert out.returncode == 2 and f"--console-port {port}" in out.stderr


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
