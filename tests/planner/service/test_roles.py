"""The shipped role files (scenarios/zenoh/roles/): deny by default, each identity may
publish only its own keys. Every test opens real Zenoh sessions the way beamrelay opens
them (:func:`planner.bus.session.zenoh_config`: the host listens with its file, every other
process connects as a client), lets one role try every key of conventions section 6, and shows
that what it may not send reached no subscriber while what it may send did.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from planner.bus.session import zenoh_config
from planner.service.up import ROLES, role_files
from tests.paths import REPO

FOLDER = REPO / "scenarios" / "zenoh" / "roles"

#: every put a process could try (conventions section 6; arm0 stands for any robot)
PUTS = [
    "beamrelay/plan", "beamrelay/targets", "beamrelay/plans", "beamrelay/targets/stream",
    "beamrelay/arm0/joint_states", "beamrelay/arm0/trajectory", "beamrelay/arm0/status",
    "beamrelay/arm0/setpoint", "beamrelay/arm0/recover", "beamrelay/camera/points",
    "beamrelay/camera/spot", "beamrelay/camera/predicted", "beamrelay/heartbeat",
    "beamrelay/calibration", "beamrelay/laser", "beamrelay/stop",
]  # fmt: skip
TOKENS = ["planner", "arm0", "camera", "tracker", "console", "ros2"]
#: what each role may do: puts, its liveliness token, serve ``plan``, ask ``plan``
MAY: dict[str, dict[str, Any]] = {
    "planner": {
        "puts": {
            "beamrelay/arm0/trajectory", "beamrelay/arm0/setpoint", "beamrelay/heartbeat",
            "beamrelay/plans", "beamrelay/calibration", "beamrelay/camera/predicted",
        },
        "token": "planner", "serve": True, "ask": False,
    },
    "driver": {
        "puts": {"beamrelay/arm0/joint_states", "beamrelay/arm0/status", "beamrelay/laser"},
        "token": "arm0", "serve": False, "ask": False,
    },
    "camera": {
        "puts": {"beamrelay/camera/points", "beamrelay/camera/spot"},
        "token": "camera", "serve": False, "ask": False,
    },
    "tracker": {
        "puts": {"beamrelay/targets/stream"}, "token": "tracker", "serve": False, "ask": False,
    },
    "console": {
        "puts": {"beamrelay/targets", "beamrelay/arm0/recover"},
        "token": "console", "serve": False, "ask": True,
    },
    "ros2": {"puts": {"beamrelay/targets"}, "token": "ros2", "serve": False, "ask": False},
}  # fmt: skip
for _may in MAY.values():
    _may["puts"].add("beamrelay/stop")  # anyone may stop the motion


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def wait_for(pred: Callable[[], bool], timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


@pytest.fixture
def opened() -> Iterator[list[Any]]:
    sessions: list[Any] = []
    yield sessions
    for s in reversed(sessions):
        s.close()


def join(opened: list[Any], role: str, endpoint: str, *, host: bool = False) -> Any:
    conf = zenoh_config(
        listen=host, endpoint=endpoint, config_file=FOLDER / f"{role}.json5", connect_timeout=20
    )
    session = zenoh.open(conf)
    opened.append(session)
    return session


class Watcher:
    """A console client listening to everything: samples, liveliness, and a queryable."""

    def __init__(self, session: Any) -> None:
        self.session = session
        self.samples: list[tuple[str, bytes]] = []
        self.tokens: set[str] = set()
        self.queries: list[bytes] = []
        self._handles = [
            session.declare_subscriber("beamrelay/**", self._on),
            session.liveliness().declare_subscriber(
                "beamrelay/alive/**", self._on_token, history=True
            ),
        ]

    def _on(self, sample: Any) -> None:
        self.samples.append((str(sample.key_expr), sample.payload.to_bytes()))

    def _on_token(self, sample: Any) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.tokens.add(str(sample.key_expr).rsplit("/", 1)[-1])

    def got(self, body: bytes) -> set[str]:
        return {k for k, b in list(self.samples) if b == body}

    def plan_replies(self) -> list[bytes]:
        replies = self.session.get("beamrelay/plan", timeout=1.0)
        return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]


def try_everything(opened: list[Any], role: str, host_role: str) -> None:
    endpoint = free_endpoint()
    host = join(opened, host_role, endpoint, host=True)
    asked: list[bytes] = []
    host.declare_queryable("beamrelay/plan", lambda q: asked.append(b"q"))
    watcher = Watcher(join(opened, "console" if role != "console" else "planner", endpoint))
    actor = join(opened, role, endpoint)

    # declarations take a moment to propagate: stop (open to all) first gets through
    def synced() -> bool:
        actor.put("beamrelay/stop", b"sync")
        return "beamrelay/stop" in watcher.got(b"sync")

    assert wait_for(synced)
    may = MAY[role]
    tokens = [actor.liveliness().declare_token(f"beamrelay/alive/{t}") for t in TOKENS]
    actor.declare_queryable("beamrelay/plan", lambda q: q.reply("beamrelay/plan", role.encode()))
    for key in PUTS:
        actor.put(key, role.encode())
    asked_before = len(asked)
    list(actor.get("beamrelay/plan", timeout=1.0))
    # what it may send arrives
    assert wait_for(lambda: watcher.got(role.encode()) >= may["puts"]), watcher.samples
    assert wait_for(lambda: may["token"] in watcher.tokens), watcher.tokens
    time.sleep(0.5)  # and anything it may not send that got through has time to arrive
    assert watcher.got(role.encode()) == may["puts"]
    assert watcher.tokens == {may["token"]}
    assert (len(asked) > asked_before) is may["ask"]
    assert (role.encode() in watcher.plan_replies()) is may["serve"]
    del tokens


@pytest.mark.parametrize("role", ROLES)
def test_each_role_may_send_only_its_own_keys(opened: list[Any], role: str) -> None:
    """Host: the console file, as ``up --zenoh-roles`` (the planner's when the console is
    the one trying; the host's own messages are not checked)."""
    try_everything(opened, role, "planner" if role == "console" else "console")


@pytest.mark.parametrize(("role", "host"), [("driver", "planner"), ("console", "driver")])
def test_the_same_whichever_process_hosts(opened: list[Any], role: str, host: str) -> None:
    """``serve`` or ``driver robot --listen`` can host the bus with their own role file."""
    try_everything(opened, role, host)


def test_every_role_file_carries_the_same_access_control() -> None:
    import json

    files = role_files(FOLDER)
    assert set(files) == set(ROLES) == set(MAY)
    blocks = [
        json.loads(zenoh.Config.from_file(str(p)).get_json("access_control"))
        for p in files.values()
    ]
    assert blocks[0]["enabled"] and blocks[0]["default_permission"] == "deny"
    assert all(b == blocks[0] for b in blocks)
    users = {line.split(":")[0] for line in (FOLDER / "credentials.txt").read_text().split()}
    assert users == {u for s in blocks[0]["subjects"] for u in s["usernames"]} == set(ROLES)
    for role, path in files.items():
        user = json.loads(zenoh.Config.from_file(str(path)).get_json("transport/auth/usrpwd"))
        assert user["user"] == role


def test_role_files_folder_must_be_complete(tmp_path: Path) -> None:
    from planner.errors import InputError

    for role in ROLES[:3]:
        (tmp_path / f"{role}.json5").write_text("{}")
    with pytest.raises(InputError, match=r"no tracker\.json5"):
        role_files(tmp_path)


def test_real_robot_driver_hosting_with_its_role_file(opened: list[Any], tmp_path: Path) -> None:
    """``beamrelay driver robot --listen --zenoh-config roles/driver.json5`` hosts the bus: a
    trajectory body from every identity but the planner's never reaches it, the planner's
    does (the driver rejects it as malformed and says so in its status)."""
    import json
    import subprocess
    import sys

    endpoint = free_endpoint()
    cmd = [
        sys.executable, "-m", "planner.cli", "driver", "robot", "--name", "arm0", "--scenario",
        str(REPO / "scenarios" / "paper_n1.yaml"), "--listen", "--endpoint", endpoint,
        "--zenoh-config", str(FOLDER / "driver.json5"),
    ]  # fmt: skip
    log = (tmp_path / "driver.log").open("w")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path)
    try:
        watcher = join(opened, "console", endpoint)
        faults: list[str] = []
        watcher.declare_subscriber(
            "beamrelay/arm0/status",
            lambda s: faults.append(str(json.loads(s.payload.to_bytes()).get("fault"))),
        )
        assert wait_for(lambda: bool(faults), 30.0), (tmp_path / "driver.log").read_text()
        for role in ("driver", "camera", "tracker", "console"):
            join(opened, role, endpoint).put("beamrelay/arm0/trajectory", b"{}")
        time.sleep(1.0)
        assert not any("rejected" in f for f in faults)
        join(opened, "planner", endpoint).put("beamrelay/arm0/trajectory", b"{}")
        assert wait_for(lambda: any("trajectory rejected" in f for f in faults))
    finally:
        proc.terminate()
        proc.wait(10)
        log.close()


ROS_KEY = "0/arm0/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_x"
ROS_TOKEN = "@ros2_lv/0/{zid}/0/0/NN/%/%/beamrelay_{role}"


@pytest.mark.parametrize("role", ROLES)
def test_only_the_ros2_identity_publishes_ros_2_topics_and_graph_tokens(
    opened: list[Any], role: str
) -> None:
    """ROS 2 keys (rmw_zenoh's data keys and graph tokens of domain 0): every identity may
    read them; only ``ros2`` (the bridge) may publish them, so no other process can pose as
    a ROS 2 node, and the bridge's own identity cannot move an arm (the table above)."""
    endpoint = free_endpoint()
    join(opened, "planner" if role == "console" else "console", endpoint, host=True)
    reader = join(opened, "console" if role != "console" else "planner", endpoint)
    got: list[str] = []
    tokens: set[str] = set()
    reader.declare_subscriber("0/**", lambda s: got.append(s.payload.to_bytes().decode()))
    reader.liveliness().declare_subscriber(
        "@ros2_lv/0/**", lambda s: tokens.add(str(s.key_expr).rsplit("_", 1)[-1]), history=True
    )
    stops: list[bytes] = []
    reader.declare_subscriber("beamrelay/stop", lambda s: stops.append(s.payload.to_bytes()))
    actor = join(opened, role, endpoint)

    def synced() -> bool:  # stop is open to all: once it arrives, the declarations are in
        actor.put("beamrelay/stop", b"sync")
        return b"sync" in stops

    assert wait_for(synced)
    token = actor.liveliness().declare_token(ROS_TOKEN.format(zid=actor.info.zid(), role=role))
    may = role == "ros2"
    for _ in range(20):
        actor.put(ROS_KEY, role)
        if wait_for(lambda: role in got, 0.1):
            break
    time.sleep(0.5)
    assert (role in got) is may, got
    assert (role in tokens) is may, tokens
    del token
