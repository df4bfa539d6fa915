"""``beamrelay record`` / ``replay``: record the simulated system, replay it onto a fresh
bus, a raw Zenoh subscriber sees the same messages (bytes, attachments) in the same order."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from drivers.record import Recorder, is_command, read, replay
from planner.errors import InputError
from tests import cli_run
from tests.drivers.conftest import free_port, wait_for
from tests.paths import REPO

SCENARIO = REPO / "scenarios" / "paper_n1.yaml"
CLI = [sys.executable, "-m", "planner.cli"]
ENV = dict(os.environ, PYTHONPATH=os.getcwd())


@pytest.mark.serial  # the joint states' 250 Hz rate is checked
def test_record_the_simulated_system_and_replay_it(
    sim_drivers: tuple[str, str], tmp_path: Path
) -> None:
    ep, prefix = sim_drivers  # the package's shared cell, its drivers up
    out = tmp_path / "session.mcap"
    rec = subprocess.run([*CLI, "record", "-o", str(out), "--duration", "2.5",
                          "--endpoint", ep, "--prefix", prefix],
                         capture_output=True, env=ENV, timeout=120)  # fmt: skip
    assert rec.returncode == 0, rec.stderr
    msgs = list(read(out))
    keys = {m.key for m in msgs}
    assert {f"{prefix}/arm0/joint_states", f"{prefix}/arm0/status", f"{prefix}/camera/spot",
            f"{prefix}/camera/points", f"@liveliness/{prefix}/alive/arm0"} <= keys  # fmt: skip
    js = [m for m in msgs if m.key.endswith("joint_states")]
    assert 2.0 * 250 * 0.8 < len(js) < 2.5 * 250 * 1.2  # 250 Hz for the 2.5 s
    assert [m.sequence for m in msgs] == sorted(m.sequence for m in msgs)
    pts = [m for m in msgs if m.key.endswith("camera/points")]
    assert pts and all(json.loads(m.attachment or b"")["schema"] == "beamrelay.points/1"
                       for m in pts)  # fmt: skip

    # replay onto a fresh bus hosted by a plain Zenoh client
    ep2 = f"tcp/127.0.0.1:{free_port()}"
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([ep2]))
    hub = zenoh.open(conf)
    got: list[tuple[str, bytes, bytes | None]] = []
    tokens: list[str] = []

    def on(s: Any) -> None:
        att = None if s.attachment is None else s.attachment.to_bytes()
        got.append((str(s.key_expr), s.payload.to_bytes(), att))

    subs = [hub.declare_subscriber(f"{prefix}/**", on),
            hub.liveliness().declare_subscriber(f"{prefix}/**",
                                                lambda s: tokens.append(str(s.key_expr)))]  # fmt: skip
    try:
        rep = subprocess.run([*CLI, "replay", str(out), "--endpoint", ep2],
                             capture_output=True, env=ENV, timeout=120)  # fmt: skip
        assert rep.returncode == 0, rep.stderr
        data = [m for m in msgs if not m.key.startswith("@")]
        assert f"{len(msgs)} messages replayed" in rep.stdout.decode()  # data and tokens
        wait_for(lambda: len(got) >= len(data), what="replayed messages")
        assert got == [(m.key, m.payload, m.attachment) for m in data]  # same bytes, same order
        assert f"{prefix}/alive/arm0" in tokens  # the tokens came back too
    finally:
        for s in subs:
            s.undeclare()
        hub.close()


class _Sample:
    def __init__(self, key: str, payload: bytes, encoding: str = "zenoh/bytes") -> None:
        self.key_expr, self.encoding, self.attachment, self.timestamp = key, encoding, None, None

        class _P:
            def to_bytes(self) -> bytes:
                return payload

        self.payload = _P()


class _Session:
    def __init__(self) -> None:
        self.put_log: list[str] = []

    def declare_subscriber(self, key: str, cb: Any, **kw: Any) -> Any:
        if not kw:  # the liveliness subscriber (history=True) is not the data one
            self.cb = cb
        return self

    def liveliness(self) -> Any:
        return self

    def undeclare(self) -> None:
        pass

    def put(self, key: str, payload: bytes, **kw: Any) -> None:
        self.put_log.append(key)

    def get(self, key: str, timeout: float = 1.0) -> list[Any]:
        from types import SimpleNamespace

        return [SimpleNamespace(ok=SimpleNamespace(key_expr="p/alive/arm0"))]


def test_commands_are_not_replayed_by_default_and_refused_on_a_live_bus(tmp_path: Path) -> None:
    buf = io.BytesIO()
    sess = _Session()
    rec = Recorder(sess, "p", buf)
    for key in ("p/arm0/trajectory", "p/arm0/joint_states", "p/heartbeat", "p/stop"):
        sess.cb(_Sample(key, b'{"a": 1}'))
    rec.close()
    path = tmp_path / "c.mcap"
    path.write_bytes(buf.getvalue())
    assert [is_command(m.key) for m in read(path)] == [True, False, True, True]
    out = _Session()
    assert replay(out, path, speed=0) == (1, 3) and out.put_log == ["p/arm0/joint_states"]
    with pytest.raises(InputError, match=r"robot drivers are alive on this bus \(p/alive/arm0\)"):
        replay(out, path, speed=0, commands=True)


def test_record_and_replay_user_mistakes(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    exist = tmp_path / "exists.mcap"
    exist.write_bytes(b"")
    cases = [
        ["replay", str(bad)],
        ["replay", str(tmp_path / "missing.mcap")],
        ["replay", str(bad), "--speed", "-1"],
        ["record", "-o", str(tmp_path / "x.txt"), "--duration", "1"],
        ["record", "-o", str(exist), "--duration", "1"],
        ["record", "-o", str(tmp_path / "x.mcap"), "--duration", "0"],
        ["recrod", "-o", "x.mcap"],
    ]
    for args in cases:
        cli_run.assert_usage_error(cli_run.beamrelay(*args))
    assert exist.read_bytes() == b""  # never lost data


@pytest.mark.parametrize(("cloud_rate", "kept"), [(1.0, 1), (0.0, 12)])
def test_point_clouds_are_decimated_and_chunks_compressed(
    tmp_path: Path, cloud_rate: float, kept: int
) -> None:
    from mcap.reader import make_reader

    buf = io.BytesIO()
    sess = _Session()
    rec = Recorder(sess, "p", buf, cloud_rate=cloud_rate)
    cloud = bytes(200_000)  # a burst of 12 clouds well inside one second
    for _ in range(12):
        sess.cb(_Sample("p/camera/points", cloud))
        sess.cb(_Sample("p/arm0/joint_states", b'{"q": [0, 0, 0, 0, 0, 0]}'))
    rec.close()
    path = tmp_path / "c.mcap"
    path.write_bytes(buf.getvalue())
    keys = [m.key for m in read(path)]
    assert keys.count("p/camera/points") == kept and keys.count("p/arm0/joint_states") == 12
    assert rec.clouds_dropped == 12 - kept
    with path.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes  # type: ignore[union-attr]
    assert chunks and {c.compression for c in chunks} == {"zstd"}
    assert path.stat().st_size < 0.1 * kept * len(cloud) + 10_000  # zeros compress
    out = _Session()
    assert replay(out, path, speed=0) == (12 + kept, 0)
