"""Event lines: one per event, UTC time, process, level, ``what key=value``; the lines
``up`` prints without a terminal; the warning for targets off every surface."""

from __future__ import annotations

import io
import logging
import re
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from planner.bus import events
from planner.service.supervisor import LogTail
from schemas.status import Reason, ServoStatus, Status


def test_event_lines_are_one_line_each_with_utc_time_and_quoted_values() -> None:
    stream = io.StringIO()
    events._listener = None  # a fresh configuration for this test
    root = logging.getLogger("beamrelay")
    before = list(root.handlers)
    try:
        events.configure("planner", stream)
        log = logging.getLogger("beamrelay.node")
        events.event(log, "verdict", id="r1", solved="1/1", execution="accepted", err=None)
        events.event(log, "stop", logging.WARNING, id="r2", reason='heartbeat lost: "x" = 1')
        events.stop()  # writes what is queued
    finally:
        for h in root.handlers[len(before) :]:
            root.removeHandler(h)
    lines = stream.getvalue().splitlines()
    stamp = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z"
    assert re.fullmatch(stamp + r" planner INFO verdict id=r1 solved=1/1 execution=accepted "
                        r"err=-", lines[0]), lines  # fmt: skip
    assert lines[1].endswith(r'WARNING stop id=r2 reason="heartbeat lost: \"x\" = 1"'), lines
    logged = time.strptime(lines[0][:19], "%Y-%m-%dT%H:%M:%S")
    assert abs(time.mktime(logged) - time.mktime(time.gmtime())) < 60  # UTC, not local


def test_verdict_fields_count_failures_and_convergence() -> None:
    ok, occluded = Status.OK, SimpleNamespace(status=Status.FAILED, reason=Reason.OCCLUDED)
    rows = [
        SimpleNamespace(status=ServoStatus.CONVERGED),
        SimpleNamespace(status=ServoStatus.NOT_SEEN),
    ]
    plan = SimpleNamespace(id="r9", execution="rejected", execution_reason="arm0: start away",
                           solutions=[SimpleNamespace(status=ok, reason=None), occluded, occluded],
                           closed_loop=SimpleNamespace(targets=rows))  # fmt: skip
    assert events.verdict_fields(plan) == {
        "id": "r9", "solved": "1/3", "failed": "occluded:2", "execution": "rejected",
        "execution_reason": "arm0: start away", "converged": "1/2"}  # fmt: skip
    sample = SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: b'{"source": "op"}'))
    assert events.stop_fields(sample) == {"source": "op", "reason": None}
    junk = SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: b"\xff"))
    assert events.stop_fields(junk)["source"] is None


def test_log_tail_gives_complete_new_lines_per_child(tmp_path: Path) -> None:
    (tmp_path / "planner.log").write_bytes(b"old line before up\n")
    tail = LogTail(tmp_path, ["planner", "arm0"])
    with (tmp_path / "planner.log").open("ab") as f:
        f.write(b"one\ntw")
    assert tail.lines() == [("planner", "one")]
    with (tmp_path / "planner.log").open("ab") as f:
        f.write(b"o\n")
    (tmp_path / "arm0.log").write_bytes(b"accepted id=r1\n")
    assert tail.lines() == [("planner", "two"), ("arm0", "accepted id=r1")]
    assert tail.lines() == []


def test_targets_off_every_surface_are_warned_with_their_distance() -> None:
    from planner.model.scene import SceneItem, SceneModel
    from planner.service.handler import OFF_SURFACE, with_surface_warnings
    from tests.planner.service.plans import as_plan

    T = np.eye(4)
    T[:3, 3] = [-0.492, -0.55, -0.065]
    board = SceneItem(
        name="board", shape="box", world_T_object=T, extents=np.array([0.3, 0.3, 0.01])
    )
    scene = SceneModel([board])
    points = np.array([[-0.49, -0.52, -0.06], [-0.49, -0.52, 0.0], [-0.492, -0.75, -0.065]])
    plan = with_surface_warnings(as_plan({}), points, scene)
    # by hand: the first lies on the top face (z = -0.06), the second 60 mm above it, the
    # third 50 mm beyond the board's -y edge (y = -0.70) in its mid-plane
    expected = [0.0, 0.06, 0.05]
    dist, _ = scene.nearest_surface(points)
    np.testing.assert_allclose(dist, expected, atol=1e-6)
    assert plan.metrics.extra["surface_distance_max"] == max(dist)
    assert plan.warnings == (
        "target 1 is 60.0 mm from the nearest surface (board): the spot lands where the beam "
        "meets a surface",
        "target 2 is 50.0 mm from the nearest surface (board): the spot lands where the beam "
        "meets a surface")  # fmt: skip
    near_points = points[:1] + np.array([0, 0, 0.9 * OFF_SURFACE])
    near = with_surface_warnings(as_plan({}), near_points, scene)
    assert near.warnings is None
