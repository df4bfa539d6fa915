"""Bus mistakes (busy port, endpoint syntax, config files): one line, exit 2, no traceback."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from planner.bus.session import check_endpoint, is_local_endpoint, open_session, zenoh_config
from planner.errors import InputError
from tests import cli_run
from tests.paths import REPO

ROOT = REPO
SCENARIO = str(ROOT / "scenarios" / "paper_n1.yaml")
EXAMPLES = ROOT / "scenarios" / "zenoh"


@pytest.fixture
def busy_port() -> Iterator[int]:
    """A loopback port held by a plain socket listener (not Zenoh)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield int(s.getsockname()[1])


run, assert_one_line = cli_run.beamrelay, cli_run.assert_usage_error


@pytest.mark.parametrize(
    "command",
    [
        ["serve", SCENARIO],
        ["driver", "robot", "--name", "arm0", "--scenario", SCENARIO, "--listen"],
        ["driver", "camera", "--scenario", SCENARIO, "--listen"],
        ["up", SCENARIO, "--duration", "5", "--no-live"],
    ],
    ids=["serve", "driver robot", "driver camera", "up"],
)
def test_busy_port(command: list[str], busy_port: int) -> None:
    proc = run(*command, "--endpoint", f"tcp/127.0.0.1:{busy_port}")
    assert_one_line(proc, f"tcp/127.0.0.1:{busy_port}", "already in use")


@pytest.mark.parametrize(
    ("endpoint", "words"),
    [
        ("127.0.0.1:7447", ["expected PROTOCOL/HOST:PORT", "tcp/127.0.0.1:7447?"]),
        ("tpc/127.0.0.1:7447", ["unknown protocol 'tpc'"]),
        ("tcp/127.0.0.1", ["expected tcp/HOST:PORT"]),
        ("tcp/127.0.0.1:99999", ["port 99999"]),
        ("tcp/", ["expected PROTOCOL/HOST:PORT"]),
    ],
)
def test_bad_endpoint(endpoint: str, words: list[str]) -> None:
    assert_one_line(run("driver", "robot", "--name", "arm0", "--scenario", SCENARIO,
                        "--endpoint", endpoint), endpoint, *words)  # fmt: skip


def test_bad_endpoint_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BEAMRELAY_ZENOH_ENDPOINT", "localhost:7447")
    proc = run("request", "--points", "0,0,0")
    assert_one_line(proc, "BEAMRELAY_ZENOH_ENDPOINT", "localhost:7447")


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp/127.0.0.1:7447",
        "tls/localhost:7447",
        "udp/[::1]:7447",
        "quic/example.org:443",
        "tcp/127.0.0.1:7447#iface=lo",
        "unixsock-stream//tmp/beamrelay.sock",
    ],
)
def test_good_endpoints_pass(endpoint: str) -> None:
    assert check_endpoint(endpoint) == endpoint


def test_protocol_missing_from_this_build_is_one_line() -> None:
    proc = run("driver", "robot", "--name", "arm0", "--scenario", SCENARIO, "--listen",
               "--endpoint", "vsock/1:2", "--zenoh-config",
               str(ROOT / "scenarios" / "zenoh" / "auth.json5"))  # fmt: skip
    assert_one_line(proc, "vsock/1:2", "cannot open the Zenoh session")


def test_config_file_mistakes(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        zenoh_config(listen=True, config_file=tmp_path / "nope.json5")
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 'peer', listen: { endpoints: ['127.0.0.1:1'] } }")
    with pytest.raises(InputError, match="Endpoints must be of the form"):
        zenoh_config(listen=True, config_file=bad)
    lost = tmp_path / "lost.json5"
    lost.write_text("{ transport: { auth: { usrpwd: { dictionary_file: 'users.txt' } } } }")
    with pytest.raises(InputError, match=r"dictionary_file: file not found: .*users\.txt"):
        zenoh_config(listen=True, config_file=lost)
    own = tmp_path / "own.json5"
    own.write_text("{ mode: 'peer', listen: { endpoints: ['tcp/127.0.0.1:0'] } }")
    with pytest.raises(InputError, match="--endpoint"):
        zenoh_config(listen=True, endpoint="tcp/127.0.0.1:1", config_file=own)
    client = tmp_path / "client.json5"
    client.write_text("{ mode: 'client' }")
    with pytest.raises(InputError, match="client cannot host"):
        zenoh_config(listen=True, config_file=client)


def test_connecting_with_a_file_waits_then_names_the_endpoint(busy_port: int) -> None:
    # a plain socket is no Zenoh host: the client gives up after its timeout
    with pytest.raises(InputError, match=f"tcp/127.0.0.1:{busy_port}"):
        open_session(
            listen=False,
            endpoint=f"tcp/127.0.0.1:{busy_port}",
            config_file=EXAMPLES / "auth.json5",
            connect_timeout=0.5,
        )


def test_up_refuses_a_file_with_its_own_endpoints(tmp_path: Path) -> None:
    own = tmp_path / "own.json5"
    own.write_text("{ mode: 'peer', listen: { endpoints: ['tcp/127.0.0.1:0'] } }")
    proc = run("up", SCENARIO, "--zenoh-config", str(own), "--duration", "1", "--no-live")
    assert_one_line(proc, "own.json5", "--endpoint")


@pytest.mark.parametrize(
    "command",
    [
        ["serve", SCENARIO],
        ["driver", "robot", "--name", "arm0", "--scenario", SCENARIO, "--listen"],
        ["driver", "camera", "--scenario", SCENARIO],
        ["request", "--points", "0,0,0"],
    ],
    ids=["serve", "driver robot", "driver camera", "request"],
)
@pytest.mark.parametrize("endpoint", ["tcp/0.0.0.0:7447", "tcp/192.168.1.10:7447", "vsock/1:2"])
def test_a_bus_beyond_loopback_needs_a_config_file(command: list[str], endpoint: str) -> None:
    assert_one_line(run(*command, "--endpoint", endpoint), endpoint, "not on loopback",
                    "--zenoh-config")  # fmt: skip


@pytest.mark.parametrize(
    ("endpoint", "local"),
    [
        ("tcp/127.0.0.1:7447", True),
        ("tcp/127.0.1.1:7447", True),
        ("tls/localhost:7447", True),
        ("udp/[::1]:7447", True),
        ("unixsock-stream//tmp/beamrelay.sock", True),
        ("tcp/0.0.0.0:7447", False),
        ("tcp/[::]:7447", False),
        ("tcp/lab-pc:7447", False),
        ("quic/example.org:443", False),
        ("vsock/1:2", False),
    ],
)
def test_which_endpoints_are_local(endpoint: str, local: bool) -> None:
    assert is_local_endpoint(endpoint) is local
    if not local:
        with pytest.raises(InputError, match="--zenoh-config"):
            zenoh_config(listen=True, endpoint=endpoint)
