"""The shipped locked-bus examples (scenarios/zenoh/), tried with real Zenoh sessions.

The clients here use the plain ``zenoh`` API with the example files as a user would copy
them (only the credentials path and a free port are written in), never the project's bus
helpers; the host of the bus is a plain session too, or the real robot driver started with
``beamrelay driver robot --listen --zenoh-config``.
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from tests.paths import REPO

ROOT = REPO
EXAMPLES = ROOT / "scenarios" / "zenoh"
TRAJECTORY = "beamrelay/arm0/trajectory"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def example(
    name: str, folder: Path = EXAMPLES, *, listen: str | None = None, connect: str | None = None
) -> zenoh.Config:
    """An example config file as zenoh reads it, with the absolute credentials path and the
    role: the host listens, a client connects (client mode: it accepts no connections)."""
    conf = zenoh.Config.from_file(str(folder / name))
    conf.insert_json5(
        "transport/auth/usrpwd/dictionary_file", json.dumps(str(folder / "credentials.txt"))
    )
    for key in ("root_ca_certificate", "listen_certificate", "listen_private_key"):
        value = json.loads(conf.get_json(f"transport/link/tls/{key}"))
        if value is not None:
            conf.insert_json5(f"transport/link/tls/{key}", json.dumps(str(folder / value)))
    if listen is not None:
        conf.insert_json5("listen/endpoints", json.dumps([listen]))
    if connect is not None:
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([connect]))
        conf.insert_json5("connect/timeout_ms", "20000")  # the host may still be starting
    return conf


def plain_client(endpoint: str) -> zenoh.Config:
    """A client with no credentials at all (an outsider on the lab network)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return conf


def wait_for(pred: Callable[[], bool], timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


class Inbox:
    """Everything a subscriber on ``beamrelay/**`` receives: (key, payload) pairs."""

    def __init__(self, session: Any) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.sub = session.declare_subscriber("beamrelay/**", self._on)

    def _on(self, sample: Any) -> None:
        self.items.append((str(sample.key_expr), sample.payload.to_bytes()))

    def has(self, key: str, body: bytes) -> bool:
        return (key, body) in self.items

    def reached_by(self, session: Any, key: str, body: bytes) -> bool:
        """Put ``body`` from ``session`` until it arrives (declarations take a moment)."""

        def attempt() -> bool:
            session.put(key, body)
            return self.has(key, body)

        return wait_for(attempt)


@pytest.fixture
def opened() -> Iterator[list[Any]]:
    sessions: list[Any] = []
    yield sessions
    for s in reversed(sessions):
        s.close()


def run_acl_bus(
    opened: list[Any], folder: Path, node: str, planner: str, endpoint: str
) -> tuple[Any, Any, Any]:
    """Host (node identity) + a driver-side subscriber, the planner and a rogue node client."""
    host = zenoh.open(example(node, folder, listen=endpoint))
    opened.append(host)
    driver = zenoh.open(example(node, folder, connect=endpoint))
    opened.append(driver)
    inbox = Inbox(driver)
    planner_s = zenoh.open(example(planner, folder, connect=endpoint))
    opened.append(planner_s)
    rogue = zenoh.open(example(node, folder, connect=endpoint))
    opened.append(rogue)
    # declarations propagate through the host: wait until a harmless message gets through
    assert inbox.reached_by(rogue, "beamrelay/arm9/joint_states", b"hello")
    return inbox, planner_s, rogue


def assert_only_the_planner_moves(inbox: Inbox, planner: Any, rogue: Any) -> None:
    for key in (TRAJECTORY, "beamrelay/arm0/setpoint", "beamrelay/heartbeat"):
        rogue.put(key, b"rogue")
    rogue.put("beamrelay/arm0/joint_states", b"rogue")  # not a motion command: allowed
    for key in (TRAJECTORY, "beamrelay/arm0/setpoint", "beamrelay/heartbeat"):
        planner.put(key, b"planner")
    assert wait_for(lambda: inbox.has("beamrelay/heartbeat", b"planner"))
    assert wait_for(lambda: inbox.has("beamrelay/arm0/joint_states", b"rogue"))
    time.sleep(0.5)  # and give anything of the rogue's that got through time to arrive
    assert inbox.has(TRAJECTORY, b"planner") and inbox.has("beamrelay/arm0/setpoint", b"planner")
    assert not [k for k, body in inbox.items if body == b"rogue" and "joint_states" not in k]


def test_unauthenticated_client_cannot_join(opened: list[Any]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    host = zenoh.open(example("auth.json5", listen=endpoint))
    opened.append(host)
    member = zenoh.open(example("auth.json5", connect=endpoint))
    opened.append(member)
    inbox = Inbox(host)
    assert inbox.reached_by(member, "beamrelay/x", b"member")
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(plain_client(endpoint))
    # a peer that only listens for the host to dial it is never dialled either
    outsider_conf = plain_client(endpoint)
    outsider_conf.insert_json5("mode", '"peer"')
    outsider_conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{free_port()}"]))
    outsider = zenoh.open(outsider_conf)
    opened.append(outsider)
    outsider.put("beamrelay/x", b"outsider")
    time.sleep(1.0)
    assert not inbox.has("beamrelay/x", b"outsider")
    assert list(outsider.info.peers_zid()) == []


def test_wrong_password_cannot_join(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    host = zenoh.open(example("auth.json5", listen=endpoint))
    try:
        conf = example("auth.json5", connect=endpoint)
        conf.insert_json5("transport/auth/usrpwd/password", '"guessed"')
        conf.insert_json5("connect/timeout_ms", "2000")  # the host is up: no need to wait
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(conf)
    finally:
        host.close()


def test_only_the_planner_identity_may_command_motion(opened: list[Any]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    inbox, planner, rogue = run_acl_bus(
        opened, EXAMPLES, "acl-node.json5", "acl-planner.json5", endpoint
    )
    assert_only_the_planner_moves(inbox, planner, rogue)


def test_a_rogue_cannot_make_the_host_dial_it(opened: list[Any]) -> None:
    """Zenoh cannot tell who is at the far end of a link it opened itself: a rogue with
    node credentials gossiping the address of a second session must not get the host to
    dial that session (the examples switch gossip off)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    inbox, _, _ = run_acl_bus(opened, EXAMPLES, "acl-node.json5", "acl-planner.json5", endpoint)
    hidden = f"tcp/127.0.0.1:{free_port()}"
    conf_b = example("acl-node.json5", listen=hidden)
    conf_b.insert_json5("access_control/enabled", "false")
    b = zenoh.open(conf_b)
    opened.append(b)
    conf_a = example("acl-node.json5", listen=f"tcp/127.0.0.1:{free_port()}")
    conf_a.insert_json5("connect/endpoints", json.dumps([endpoint, hidden]))
    conf_a.insert_json5("scouting/gossip/enabled", "true")
    a = zenoh.open(conf_a)
    opened.append(a)
    time.sleep(2.0)
    b.put(TRAJECTORY, b"rogue")
    time.sleep(1.0)
    assert not inbox.has(TRAJECTORY, b"rogue")


def test_every_example_carries_the_same_access_control() -> None:
    blocks = {
        name: json.loads(zenoh.Config.from_file(str(EXAMPLES / name)).get_json("access_control"))
        for name in ("acl-node.json5", "acl-planner.json5", "tls-node.json5", "tls-planner.json5")
    }
    first = next(iter(blocks.values()))
    assert first["enabled"] and all(b == first for b in blocks.values())
    users = {line.split(":")[0] for line in (EXAMPLES / "credentials.txt").read_text().split()}
    in_subjects = {u for s in first["subjects"] for u in s.get("usernames", [])}
    assert users == in_subjects  # an unlisted user would get the default permission


def make_certs(folder: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed: cannot make test certificates")
    subprocess.run(
        ["sh", str(EXAMPLES / "make-test-certs.sh"), str(folder / "tls")],
        check=True,
        capture_output=True,
    )


def test_tls_variant(tmp_path: Path, opened: list[Any]) -> None:
    for name in ("tls-node.json5", "tls-planner.json5", "credentials.txt"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    make_certs(tmp_path)
    port = free_port()
    endpoint = f"tls/localhost:{port}"
    inbox, planner, rogue = run_acl_bus(
        opened, tmp_path, "tls-node.json5", "tls-planner.json5", endpoint
    )
    assert_only_the_planner_moves(inbox, planner, rogue)
    with pytest.raises(zenoh.ZError):  # plain TCP to the TLS port does not get in
        zenoh.open(plain_client(f"tcp/127.0.0.1:{port}"))


def robot_status_faults(session: Any) -> list[str]:
    faults: list[str] = []

    def on(sample: Any) -> None:
        faults.append(str(json.loads(sample.payload.to_bytes()).get("fault")))

    session.declare_subscriber("beamrelay/arm0/status", on)
    return faults


def test_real_robot_driver_drops_a_rogue_trajectory(opened: list[Any], tmp_path: Path) -> None:
    """``beamrelay driver robot --listen --zenoh-config`` hosts the bus; a trajectory body
    from the node identity never reaches it, the same body from the planner identity does
    (the driver rejects it as malformed and says so in its status)."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    cmd = [
        sys.executable, "-m", "planner.cli", "driver", "robot", "--name", "arm0", "--scenario",
        str(ROOT / "scenarios" / "paper_n1.yaml"), "--listen", "--endpoint", endpoint,
        "--zenoh-config", str(EXAMPLES / "acl-node.json5"),
    ]  # fmt: skip
    log = (tmp_path / "driver.log").open("w")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path)
    try:
        watcher = zenoh.open(example("acl-node.json5", connect=endpoint))
        opened.append(watcher)
        faults = robot_status_faults(watcher)
        assert wait_for(lambda: bool(faults), 30.0), (tmp_path / "driver.log").read_text()
        rogue = zenoh.open(example("acl-node.json5", connect=endpoint))
        opened.append(rogue)
        planner = zenoh.open(example("acl-planner.json5", connect=endpoint))
        opened.append(planner)
        rogue.put(TRAJECTORY, b"{}")
        time.sleep(1.0)
        assert not any("rejected" in f for f in faults)
        planner.put(TRAJECTORY, b"{}")
        assert wait_for(lambda: any("trajectory rejected" in f for f in faults))
    finally:
        proc.terminate()
        proc.wait(10)
        log.close()
