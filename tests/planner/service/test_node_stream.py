"""Trajectories over the body limit: split into chunks at sample boundaries and streamed so
that a driver never holds more than one queued behind the one it plays. The drivers here are
written with plain zenoh and keep the real drivers' queueing rule (a trajectory arriving while
one plays must start at that one's last sample; it starts when that one ends; a newer one
replaces the queued one)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.bus.ids import chunk_id
from planner.bus.session import MAX_PAYLOAD_BYTES, Keys, open_session
from planner.model.system import System
from planner.service.execution import ExecuteError
from planner.service.heartbeat import BusAddress
from planner.service.node import PlannerNode, RequestHandler, make_plan_fn
from planner.service.stream import CHUNK_BYTES, split_edges, split_trajectory
from schemas.messages import JointTrajectory
from tests.drivers.conftest import free_port, wait_for
from tests.planner.raw_zenoh import Inbox, ask, raw_session
from tests.planner.service.plans import as_plan
from tests.planner.service.test_node import reachable_targets, system_with_camera

PREFIX = "streamtest"
SMALL_CHUNKS = 96 * 1024  # bytes: a few seconds of motion become several chunks


@dataclass
class Playing:
    id: str
    q: np.ndarray
    duration: float
    start: float  # monotonic s


class QueueingDriver:
    """One robot: plays a trajectory for its duration, queues one more behind it."""

    def __init__(self, session: Any, robot: str, names: list[str], q: np.ndarray) -> None:
        self.session, self.robot, self.names, self.q = session, robot, names, q
        self.running: Playing | None = None
        self.queued: Playing | None = None
        self.reject_prefix = "\0"  # trajectories whose id starts with it are refused
        self.log: list[dict[str, Any]] = []  # per arrival: id, what ran, what was queued
        self.received: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._token = session.liveliness().declare_token(f"{PREFIX}/alive/{robot}")
        self._sub = session.declare_subscriber(f"{PREFIX}/{robot}/trajectory", self._on_traj)
        self._thread = threading.Thread(target=self._publish_states, daemon=True)
        self._thread.start()

    def advance(self, now: float) -> None:
        """Let time pass: the running trajectory ends, the queued one takes its place."""
        while self.running is not None and now >= self.running.start + self.running.duration:
            self.q = self.running.q[-1]
            end = self.running.start + self.running.duration
            self.running, self.queued = self.queued, None
            if self.running is not None:
                self.running.start = end

    def _publish_states(self) -> None:
        while not self._stop.wait(0.01):
            with self._lock:
                self.advance(time.monotonic())
                q = self.q if self.running is None else self.running.q[0]
            body = {"schema": "beamrelay.joint_state/1", "t": time.time(), "names": self.names,
                    "q": np.asarray(q).tolist(), "qd": [0.0] * len(self.names)}  # fmt: skip
            self.session.put(f"{PREFIX}/{self.robot}/joint_states", json.dumps(body))

    def _on_traj(self, sample: Any) -> None:
        msg = json.loads(sample.payload.to_bytes())
        now = time.monotonic()
        self.received.append(msg)
        q = np.asarray(msg["q"])
        with self._lock:
            self.advance(now)
            left = (
                None if self.running is None else self.running.start + self.running.duration - now
            )
            self.log.append({"id": msg["id"], "running": self.running and self.running.id,
                             "queued": self.queued and self.queued.id, "left": left})  # fmt: skip
            reason = "refused by the test" if msg["id"].startswith(self.reject_prefix) else None
            ref = self.q if self.running is None else self.running.q[-1]
            if reason is None and np.max(np.abs(q[0] - ref)) > 0.01:
                reason = f"q[0]: starts {np.max(np.abs(q[0] - ref)):.4f} rad away"
            if reason is None:
                playing = Playing(msg["id"], q, float(msg["t"][-1]), now)
                if self.running is None:
                    self.running = playing
                else:
                    self.queued = playing
        ack = {"id": msg["id"], "accepted": reason is None, "reason": reason, "t": time.time()}
        body = {"schema": "beamrelay.status/1", "robot": self.robot, "t": time.time(),
                "mode": "following", "trajectory": ack}  # fmt: skip
        self.session.put(f"{PREFIX}/{self.robot}/status", json.dumps(body))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sub.undeclare()
        self._token.undeclare()


class Rig:
    def __init__(self, system: System) -> None:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.hub = open_session(listen=True, endpoint=endpoint)
        self.node = PlannerNode(RequestHandler(system, make_plan_fn(system, {})), self.hub,
                                Keys(PREFIX), bus=BusAddress(endpoint))  # fmt: skip
        self.node.execution.chunk_bytes = SMALL_CHUNKS
        self.node.tracks.margin = 0.2
        self.node.start()
        self.client, self.side = raw_session(endpoint), raw_session(endpoint)
        robot = system.robots[0]
        self.driver = QueueingDriver(self.side, "arm0", list(robot.joint_names), robot.home)
        self.stops = Inbox(self.client, f"{PREFIX}/stop")
        wait_for(lambda: "arm0" in self.node.alive and self.node.joints.get("arm0") is not None,
                 20.0, "driver seen by the node")  # fmt: skip

    def execute(self, points: np.ndarray, rid: str) -> tuple[bool, dict[str, Any]]:
        body = {"schema": "beamrelay.request/1", "id": rid, "points": points.tolist(),
                "execute": True}  # fmt: skip
        ok, reply = ask(self.client, f"{PREFIX}/plan", json.dumps(body).encode(), timeout=60)
        return ok, json.loads(reply)

    def close(self) -> None:
        self.stops.close()
        self.driver.close()
        self.client.close()
        self.side.close()
        self.node.close()
        self.hub.close()


@pytest.fixture(scope="module")
def system() -> System:
    return system_with_camera()


@pytest.fixture
def rig(system: System) -> Iterator[Rig]:
    r = Rig(system)
    yield r
    r.close()


def plan_q(plan: dict[str, Any]) -> np.ndarray:
    t = np.asarray(plan["trajectory"]["t"])
    keep = np.concatenate([[True], np.diff(t) > 0])
    return np.asarray(plan["trajectory"]["q"]["arm0"])[keep]


def test_a_long_trajectory_is_streamed_one_queued_chunk_at_a_time(rig: Rig, system: System) -> None:
    ok, plan = rig.execute(reachable_targets(system, 8, seed=3), "long")
    assert ok, plan
    n = plan["execution_chunks"]
    assert plan["execution"] == "accepted" and plan["execution_reason"] is None and n >= 4
    duration = float(plan["trajectory"]["t"][-1])
    wait_for(lambda: len(rig.driver.received) == n, duration + 10.0, "every chunk")
    got = rig.driver.received
    assert [m["id"] for m in got] == [chunk_id("long", k, n) for k in range(1, n + 1)]
    assert {m["session"] for m in got} == {rig.node.session_id}
    sizes = [len(json.dumps(m)) for m in got]
    assert max(sizes) <= SMALL_CHUNKS
    # chunk k + 1 arrived while chunk k played (k >= 2): never two queued, none replaced
    log = rig.driver.log
    assert log[0]["running"] is None and log[1] == {**log[1], "running": got[0]["id"]}
    for k in range(2, n):
        assert (log[k]["running"], log[k]["queued"]) == (got[k - 1]["id"], None), log[k]
    left = [entry["left"] for entry in log[2:]]
    print(f"{n} chunks of {np.mean([m['t'][-1] for m in got]):.2f} s: each next one arrived "
          f"{min(left):.2f}-{max(left):.2f} s before the running one ended")  # fmt: skip
    # joined at the shared boundary samples, the chunks are the plan's trajectory
    joined = np.concatenate([np.asarray(got[0]["q"])] + [np.asarray(m["q"])[1:] for m in got[1:]])
    np.testing.assert_array_equal(joined, plan_q(plan))
    assert sum(m["t"][-1] for m in got) == pytest.approx(duration, abs=1e-9)
    assert not rig.stops.bodies()


def test_a_later_chunk_rejected_stops_the_robots(rig: Rig, system: System) -> None:
    rig.driver.reject_prefix = "later#3/"
    ok, plan = rig.execute(reachable_targets(system, 8, seed=4), "later")
    assert ok and plan["execution"] == "accepted"  # chunks 1 and 2 were accepted
    n = plan["execution_chunks"]
    assert n >= 4
    wait_for(lambda: bool(rig.stops.bodies()), 30.0, "a stop on the bus")
    stop = rig.stops.bodies()[0]
    assert stop["source"] == "planner"
    assert f"request later: chunk 3/{n}: arm0: refused by the test" in stop["reason"]
    time.sleep(1.0)
    assert [m["id"] for m in rig.driver.received][-1] == chunk_id("later", 3, n)


def test_execute_is_refused_while_chunks_remain_and_a_stop_ends_the_stream(
    rig: Rig, system: System
) -> None:
    ok, plan = rig.execute(reachable_targets(system, 8, seed=5), "first")
    assert ok and plan["execution"] == "accepted"
    n = plan["execution_chunks"]
    ok, err = rig.execute(reachable_targets(system, 1, seed=6), "second")
    assert not ok and err["field"] == "execute"
    assert err["error"].startswith(f"the robots are executing request first in {n} chunks")
    rig.client.put(f"{PREFIX}/stop", b"any body stops")
    wait_for(lambda: rig.node.execution.busy() is None, 5.0, "stream ended by the stop")
    sent = len(rig.driver.received)
    time.sleep(1.5)
    assert len(rig.driver.received) == sent < n + 1  # nothing sent after the stop


def big_plan(n: int, robots: tuple[str, ...] = ("arm0",), rest_every: int | None = 300) -> dict:
    """A plan.json with an n-sample trajectory at 500 Hz: moves from rest to rest, every
    robot at rest (qd = qdd = 0) on every ``rest_every``-th sample (never: None)."""
    rng = np.random.default_rng(7)
    t = np.arange(n) * 0.002
    traj: dict[str, Any] = {"t": t.tolist(), "q": {}, "qd": {}, "qdd": {}}
    for r in robots:
        qd = rng.normal(0, 0.05, (n, 6))
        qdd = rng.normal(0, 0.5, (n, 6))
        if rest_every is not None:
            qd[::rest_every] = qdd[::rest_every] = 0.0
        traj["q"][r] = np.cumsum(qd * 0.002, axis=0).tolist()
        traj["qd"][r], traj["qdd"][r] = qd.tolist(), qdd.tolist()
    names = {r: [f"j{k}" for k in range(6)] for r in robots}
    return {"robots": list(robots), "joint_names": names, "trajectory": traj}


def resting(plan: dict[str, Any]) -> np.ndarray:
    traj = plan["trajectory"]
    return np.all([(np.abs(traj["qd"][r]).max(1) == 0) & (np.abs(traj["qdd"][r]).max(1) == 0)
                   for r in plan["robots"]], axis=0)  # fmt: skip


def test_the_paper_sized_trajectory_splits_under_the_body_limit_where_robots_rest() -> None:
    """52,707 samples (the paper grid's 1000 targets): about 17 MB per robot in one body."""
    plan = big_plan(52_707, ("arm0", "arm1"))
    chunks = split_trajectory(as_plan(plan), "grid", "sess")
    t, q = np.asarray(plan["trajectory"]["t"]), np.asarray(plan["trajectory"]["q"]["arm1"])
    rest = resting(plan)
    n, start, pieces = len(chunks), 0, []
    assert n >= 5
    for k, c in enumerate(chunks, start=1):
        assert c.id == f"grid#{k}/{n}"
        for robot, body in c.bodies.items():
            assert len(body) <= CHUNK_BYTES < MAX_PAYLOAD_BYTES
            msg = JointTrajectory.model_validate_json(body)
            assert (msg.robot, msg.id, msg.session, msg.t[0]) == (robot, c.id, "sess", 0.0)
        msg = JointTrajectory.model_validate_json(c.bodies["arm1"])
        end = start + len(msg.t) - 1  # this chunk covers samples start..end
        assert rest[start] and (rest[end] or end == len(t) - 1)  # split where robots rest
        np.testing.assert_allclose(np.asarray(msg.t) + t[start], t[start : end + 1], atol=1e-9)
        assert (c.t0, c.duration) == pytest.approx((t[start], t[end] - t[start]))
        pieces.append(np.asarray(msg.q)[0 if k == 1 else 1 :])
        start = end
    assert start == len(t) - 1
    np.testing.assert_array_equal(np.concatenate(pieces), q)
    sizes = [c.nbytes for c in chunks]
    assert max(sizes) < 1.5 * min(sizes)  # about even


def test_a_trajectory_that_never_rests_is_refused_unless_moving_splits_are_allowed() -> None:
    plan = big_plan(30_000, rest_every=None)
    with pytest.raises(
        ExecuteError,
        match=r"exceeds the 3145728-byte message size and cannot "
        r"be split where the robots rest: they move for 60\.0 s without a stop",
    ):
        split_trajectory(as_plan(plan), "r", "sess")
    chunks = split_trajectory(as_plan(plan), "r", "sess", at_rest_only=False)
    assert len(chunks) >= 3 and all(c.nbytes <= CHUNK_BYTES for c in chunks)
    plan = big_plan(30_000, rest_every=20_000)  # a rest point, but chunks would be too long
    with pytest.raises(ExecuteError, match=r"move for 40\.0 s without a stop"):
        split_trajectory(as_plan(plan), "r", "sess")


def test_split_edges() -> None:
    cands = np.array([3, 5, 9, 12, 16])
    assert split_edges(cands, 20, 7) == [0, 5, 12, 19]
    assert split_edges(cands, 20, 19) == [0, 19]
    assert split_edges(np.array([10]), 20, 7) is None
    edges = split_edges(np.arange(1, 99), 100, 10)  # any sample may be an edge: even shares
    assert edges is not None and len(edges) == 11 and edges[-1] == 99
    assert max(np.diff(edges)) <= 10
    np.testing.assert_allclose(edges, np.arange(11) * 9.9, atol=0.5)


def test_a_trajectory_that_fits_stays_one_message_with_the_request_id() -> None:
    chunks = split_trajectory(as_plan(big_plan(2000)), "small", "sess")
    assert len(chunks) == 1 and chunks[0].id == "small" and chunks[0].t0 == 0.0
    assert chunks[0].duration == pytest.approx(1999 * 0.002)


def test_chunk_ids_fit_the_id_length() -> None:
    rid = "x" * 256
    cid = chunk_id(rid, 12, 40)
    assert len(cid) == 256 and cid.endswith("#12/40")
    for c in split_trajectory(as_plan(big_plan(30_000)), rid, "sess"):
        assert JointTrajectory.model_validate_json(c.bodies["arm0"]).id == c.id


@pytest.mark.serial  # real-time playback on a driver process
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; -rR lists a rerun
def test_chunks_play_back_to_back_on_the_sim_driver(tmp_path: Path) -> None:
    """The real robot driver (``beamrelay driver robot --backend sim``, its own process as in
    production): every chunk is accepted, queued behind the one that plays and started when
    it ends, without a settle, a brake or a safety stop in between; the arm ends where the
    plan ends."""
    from planner.service.node import handler_from_scenario
    from tests.test_e2e import SCENARIO, board_targets

    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(SCENARIO)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_session(listen=True, endpoint=endpoint)
    node = PlannerNode(handler_from_scenario(scenario), hub, Keys(PREFIX),
                       bus=BusAddress(endpoint))  # fmt: skip
    node.execution.chunk_bytes = 2 * SMALL_CHUNKS
    node.start()
    client = raw_session(endpoint)
    statuses: list[dict[str, Any]] = []
    states: list[dict[str, Any]] = []
    subs = [client.declare_subscriber(f"{PREFIX}/arm0/status", lambda s: statuses.append(
                json.loads(s.payload.to_bytes()))),
            client.declare_subscriber(f"{PREFIX}/arm0/joint_states", lambda s: states.append(
                json.loads(s.payload.to_bytes())))]  # fmt: skip
    argv = [sys.executable, "-m", "planner.cli", "driver", "robot", "--name", "arm0",
            "--backend", "sim", "--scenario", str(scenario), "--endpoint", endpoint,
            "--prefix", PREFIX]  # fmt: skip
    log = (tmp_path / "driver.log").open("wb")
    driver = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_for(lambda: "arm0" in node.alive and node.joints.get("arm0") is not None, 60.0,
                 "the driver")  # fmt: skip
        body = {"schema": "beamrelay.request/1", "id": "sim", "execute": True,
                "points": board_targets(10, seed=8).tolist()}  # fmt: skip
        ok, reply = ask(client, f"{PREFIX}/plan", json.dumps(body).encode(), timeout=60)
        plan = json.loads(reply)
        assert ok and plan["execution"] == "accepted", plan
        n, duration = plan["execution_chunks"], float(plan["trajectory"]["t"][-1])
        q_end = np.asarray(plan["trajectory"]["q"]["arm0"][-1])

        def at_rest_at_the_end() -> bool:
            last = states[-1]
            return bool(np.max(np.abs(np.subtract(last["q"], q_end))) < 1e-9
                        and np.max(np.abs(last["qd"])) == 0.0)  # fmt: skip

        wait_for(at_rest_at_the_end, duration + 20.0, "the arm at rest at the end")
        time.sleep(0.3)
        verdicts = {m["trajectory"]["id"]: m["trajectory"] for m in statuses if m["trajectory"]}
        first = next(k for k, m in enumerate(statuses) if (m["trajectory"] or {}).get("id"))
        modes = [m["mode"] for m in statuses[first:]]
        faults = {m["fault"] for m in statuses[first:]} - {None}
        print(f"{duration:.1f} s in {n} chunks; driver modes: {list(dict.fromkeys(modes))}")
        assert n >= 4 and not faults, faults
        assert [verdicts.get(chunk_id("sim", k, n), {}).get("accepted") for k in
                range(1, n + 1)] == [True] * n  # fmt: skip
        moving = modes[: len(modes) - modes[::-1].index("following")]
        assert set(moving) <= {"approach", "following"}, list(dict.fromkeys(moving))
    finally:
        driver.terminate()
        driver.wait(20)
        log.close()
        for sub in subs:
            sub.undeclare()
        client.close()
        node.close()
        hub.close()
