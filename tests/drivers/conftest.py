"""Shared fixtures of the driver tests: a private Zenoh bus on a free loopback port."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import pytest

from planner.bus.session import Keys, open_session
from tests.paths import SCENARIOS


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


def stop_processes(procs: Iterable[subprocess.Popen[bytes]]) -> None:
    """SIGTERM every process still running, then wait 5 s for each (SIGKILL after)."""
    procs = list(procs)
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def wait_for(pred: Callable[[], bool], timeout: float = 10.0, what: str = "condition") -> None:
    """Poll ``pred`` until true; fail the test (not hang) after ``timeout`` s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def wait_for_nodes(
    endpoint: str, prefix: str, nodes: tuple[str, ...], timeout: float = 60.0
) -> None:
    """Wait until the process hosting ``endpoint`` (a loopback TCP port) accepts connections
    and every node in ``nodes`` has its liveliness token ``<prefix>/alive/<node>`` on the bus;
    fail the test after ``timeout`` s for each of the two."""

    def accepts() -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", int(endpoint.rsplit(":", 1)[1]))) == 0

    wait_for(accepts, timeout, f"{endpoint} accepting connections")
    client = raw_session(endpoint)
    try:

        def tokens() -> bool:
            return all(
                any(r.ok is not None for r in client.liveliness().get(f"{prefix}/alive/{n}",
                                                                       timeout=1.0))
                for n in nodes
            )  # fmt: skip

        wait_for(tokens, timeout, f"liveliness tokens of {', '.join(nodes)}")
    finally:
        client.close()


def raw_session(endpoint: str) -> Any:
    """A plain Zenoh client (no project helpers): peer, connects to ``endpoint`` only."""
    import json

    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(conf)


class Heartbeats:
    """Publishes ``{schema, t, session, seq}`` on ``<prefix>/heartbeat`` at ``rate`` Hz from a
    thread, with a plain Zenoh session, until :meth:`stop`. ``sent`` holds the UNIX times."""

    def __init__(self, session: Any, prefix: str, name: str, rate: float = 100.0) -> None:
        import threading

        self.session, self.key, self.name, self.rate = session, f"{prefix}/heartbeat", name, rate
        self.sent: list[float] = []
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import json

        pub = self.session.declare_publisher(self.key)
        seq = 0
        while not self._halt.wait(1.0 / self.rate):
            t = time.time()
            body = {"schema": "beamrelay.heartbeat/1", "t": t, "session": self.name, "seq": seq}
            pub.put(json.dumps(body).encode())
            self.sent.append(t)
            seq += 1
        pub.undeclare()

    def stop(self) -> float:
        """Stop beating; the UNIX time of the last heartbeat sent."""
        self._halt.set()
        self._thread.join(5.0)
        return self.sent[-1]


@pytest.fixture(scope="package")
def sim_drivers() -> Iterator[tuple[str, str]]:
    """One simulated cell for the driver package's system tests that only read it or move
    the arm and leave it at rest (collect, record): ``beamrelay driver robot --listen`` and
    ``driver camera`` on ``scenarios/paper_n1.yaml``; yields (endpoint, prefix). Started on
    first use, stopped after the package's last test (not kept through the other packages'
    real-time probes). A test that changes the cell (another scenario, a kill) starts its own."""
    ep, prefix = f"tcp/127.0.0.1:{free_port()}", "brsim"
    cli = [sys.executable, "-m", "planner.cli", "driver"]
    bus = ["--scenario", str(SCENARIOS / "paper_n1.yaml"), "--endpoint", ep, "--prefix", prefix]
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    robot = subprocess.Popen([*cli, "robot", "--name", "arm0", "--listen", *bus],
                             stderr=subprocess.DEVNULL, env=env)  # fmt: skip
    camera = subprocess.Popen([*cli, "camera", "--stride", "8", "--seed", "3", *bus],
                              stderr=subprocess.DEVNULL, env=env)  # fmt: skip
    try:
        wait_for_nodes(ep, prefix, ("arm0", "camera"))
        yield ep, prefix
    finally:
        for p in (camera, robot):
            p.terminate()
            p.wait(30)
