"""``beamrelay up``'s child command lines (the live behaviour is in tests/test_e2e.py)."""

from __future__ import annotations

import sys
from pathlib import Path

from planner.service.up import child_commands


def test_child_commands_cover_every_node_with_the_bus_options() -> None:
    s = Path("/x/s.yaml")
    argv = child_commands(s, ["arm0", "arm1"], endpoint="tcp/127.0.0.1:9", prefix="p")
    assert list(argv) == ["planner", "camera", "arm0", "arm1"]
    bus = ["--endpoint", "tcp/127.0.0.1:9", "--prefix", "p"]
    cli = [sys.executable, "-m", "planner.cli"]
    assert argv["planner"] == [*cli, "serve", str(s), "--connect", *bus]
    assert argv["camera"] == [
        *cli,
        "driver",
        "camera",
        "--backend",
        "sim",
        "--scenario",
        str(s),
        *bus,
    ]
    assert argv["arm1"] == [
        *cli, "driver", "robot", "--name", "arm1", "--backend", "sim", "--scenario", str(s), *bus
    ]  # fmt: skip
    ur = child_commands(s, ["arm0"], backend="ur", endpoint="e", camera=False)
    assert list(ur) == ["planner", "arm0"] and "--prefix" not in ur["arm0"]
    assert ur["arm0"][ur["arm0"].index("--backend") + 1] == "ur"
