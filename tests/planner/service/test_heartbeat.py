"""The planner heartbeat comes from a child process: it keeps beating while the planner holds
the GIL, and stops when the planner is stopped, killed or stalled. Beats are received with
plain zenoh; where the planner runs in this process they are timed by a listener *process*
(a subscriber callback here would wait for the same GIL)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.robot.node import HEARTBEAT_TIMEOUT
from planner.bus.session import Keys, open_session
from planner.data import shipped_scenario
from planner.service.heartbeat import (
    HEARTBEAT_RATE,
    STOP,
    TICK,
    BusAddress,
    beat_loop,
    process_state,
)
from planner.service.node import PlannerNode, RequestHandler, make_plan_fn
from schemas.messages import Heartbeat
from tests.drivers.conftest import free_port, wait_for
from tests.fake_clock import FakeClock
from tests.planner.raw_zenoh import Inbox, ask, raw_session
from tests.planner.service.test_node import system_with_camera

pytestmark = pytest.mark.timeout(240)
PREFIX = "hbtest"
LISTENER = """
import json, os, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
session = zenoh.open(conf)
times = []
sub = session.declare_subscriber(sys.argv[2], lambda s: times.append(time.monotonic()))
print("ready", flush=True)
sys.stdin.read()
print(json.dumps(times), flush=True)
os._exit(0)  # no session teardown at exit: it can hang
"""


class Listener:
    """A separate process timing every sample on ``key`` (monotonic clock, shared by all
    processes on Linux)."""

    def __init__(self, endpoint: str, key: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", LISTENER, endpoint, key],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)  # fmt: skip
        assert self.proc.stdout is not None
        assert self.proc.stdout.readline().strip() == b"ready"

    def times(self) -> np.ndarray:
        out, _ = self.proc.communicate(b"", timeout=30)
        return np.asarray(json.loads(out.decode().splitlines()[-1]))


def hold_the_gil(seconds: float) -> tuple[float, float]:
    """One C call that keeps the GIL for at least ``seconds`` s (longer calls until one
    does); its start and end (monotonic s)."""
    n = 2_000_000
    while True:
        t0 = time.monotonic()
        sum(range(n))
        t1 = time.monotonic()
        if t1 - t0 >= seconds:
            return t0, t1
        n = int(n * max(2.0, 1.3 * seconds / max(t1 - t0, 1e-4)))


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; -rR lists a rerun
@pytest.mark.parametrize("where", ["process", "thread"])
def test_a_planner_holding_the_gil_does_not_silence_the_process_heartbeat(where: str) -> None:
    """What the solvers do (one C call holding the GIL for up to a second): the heartbeat
    thread of the planner process falls silent for the whole call, its child process
    does not."""
    system = system_with_camera()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_session(listen=True, endpoint=endpoint)
    bus = BusAddress(endpoint) if where == "process" else None
    node = PlannerNode(RequestHandler(system, make_plan_fn(system, {})), hub, Keys(PREFIX),
                       bus=bus).start()  # fmt: skip
    try:
        listener = Listener(endpoint, f"{PREFIX}/heartbeat")
        time.sleep(0.5)
        t0, t1 = hold_the_gil(0.8)
        held = t1 - t0
        time.sleep(0.3)
        times = listener.times()
    finally:
        node.close()
        hub.close()
    during = times[(times >= t0 - 0.05) & (times <= t1 + 0.05)]
    gap = float(np.max(np.diff(np.concatenate([[t0], during, [t1]]))))
    print(f"{where}: GIL held {1e3 * held:.0f} ms, longest heartbeat gap {1e3 * gap:.0f} ms")
    if where == "process":
        assert gap < HEARTBEAT_TIMEOUT  # the drivers would brake a moving arm at this gap
    else:  # the old way: silent while the GIL is held
        assert gap > 0.5 * held


T0 = 1000.0


class Parent:
    """The parent's side of :func:`beat_loop` on a fake clock: tick bytes at ``ticks`` (s
    after T0), ``end`` (STOP, or b"": the pipe closes) at ``end_at``, the parent stopped
    (state ``T``) during the ``stopped`` spans."""

    def __init__(self, ticks: Any, end_at: float, end: bytes = STOP,
                 stopped: tuple[tuple[float, float], ...] = ()) -> None:  # fmt: skip
        self.clock = FakeClock(T0)
        self.events = sorted([(T0 + t, TICK) for t in ticks] + [(T0 + end_at, end)])
        self.stopped = stopped
        self.beats: list[tuple[float, dict[str, Any]]] = []
        self.first: list[float] = []

    def read(self, timeout: float) -> bytes | None:
        deadline = self.clock() + timeout
        if self.events and self.events[0][0] <= deadline:
            t, data = self.events.pop(0)
            self.clock.t = max(self.clock.t, t)
            return data
        self.clock.t = deadline
        return None

    def state(self, pid: int) -> str:
        t = self.clock() - T0
        return "T" if any(a <= t < b for a, b in self.stopped) else "S"

    def run(self, stall: float) -> str:
        def put(body: bytes) -> None:
            self.beats.append((self.clock() - T0, json.loads(body)))

        return beat_loop(put, "sess", os.getppid(), 100.0, stall, -1,
                         lambda: self.first.append(self.clock() - T0), clock=self.clock,
                         read=self.read, state=self.state)  # fmt: skip

    def slots(self) -> list[int]:
        """The 10 ms beat slots (index from T0) in which a beat went out."""
        return [round(100 * t) for t, _ in self.beats]


def every(start: float, stop: float, step: float = 0.05) -> Any:
    return np.arange(start, stop + 1e-9, step)


def test_child_beats_only_while_the_parent_ticks_and_ends_on_stop() -> None:
    """Ticks every 50 ms up to 0.505 s, none until 1.205 s (an unresponsive parent), ticks
    again, STOP at 1.555 s; stall 0.3 s: beats in every 10 ms slot up to 0.505 + 0.3 s,
    none after, again from the first slot after the tick at 1.205 s up to the stop."""
    parent = Parent([*every(0.055, 0.505), *every(1.205, 1.505)], 1.555)
    assert parent.run(stall=0.3) == "stopped by the parent"
    assert parent.slots() == [*range(0, 81), *range(121, 156)]
    assert [t for t, _ in parent.beats] == pytest.approx(
        [k / 100 for k in parent.slots()], abs=1e-9
    )
    seqs = [b["seq"] for _, b in parent.beats]
    assert seqs == list(range(len(seqs)))  # seq continues across the silence
    assert {b["session"] for _, b in parent.beats} == {"sess"}
    assert all(Heartbeat.model_validate(b).session == "sess" for _, b in parent.beats)
    assert parent.first == [0.0]


def test_child_is_silent_while_the_parent_is_stopped() -> None:
    parent = Parent(every(0.055, 0.955), 0.995, stopped=((0.305, 0.605),))
    assert parent.run(stall=3.0) == "stopped by the parent"
    assert parent.slots() == [*range(0, 31), *range(61, 100)]


def test_child_ends_when_the_pipe_closes() -> None:
    parent = Parent(every(0.055, 0.155), 0.195, end=b"")
    assert parent.run(stall=3.0) == "the parent closed the pipe (exited)"
    assert parent.slots() == list(range(0, 20))
    read_fd, write_fd = os.pipe()  # the real pipe: a tick, then the parent exits
    os.write(write_fd, TICK)
    os.close(write_fd)
    try:
        ended = beat_loop(lambda b: None, "sess", os.getppid(), 100.0, 3.0, read_fd,
                          lambda: None)  # fmt: skip
    finally:
        os.close(read_fd)
    assert ended == "the parent closed the pipe (exited)"


def test_process_state_reads_linux_states() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        wait_for(lambda: process_state(proc.pid) == "S", 10.0, "sleeping child")
        os.kill(proc.pid, signal.SIGSTOP)
        wait_for(lambda: process_state(proc.pid) == "T", 5.0, "stopped child")
        os.kill(proc.pid, signal.SIGCONT)
        wait_for(lambda: process_state(proc.pid) == "S", 5.0, "continued child")
    finally:
        proc.kill()
        proc.wait()
    assert process_state(proc.pid) is None  # reaped: gone


# --- a real `beamrelay serve` process --------------------------------------------------
def heartbeat_children(pid: int) -> list[int]:
    """Live child processes of ``pid`` running the heartbeat module (Linux /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            cmd = (d / "cmdline").read_bytes()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid and fields[0] != "Z" and b"planner.service.heartbeat" in cmd:
            out.append(int(d.name))
    return out


def alive(pid: int) -> bool:
    return process_state(pid) not in (None, "Z")


class Served:
    """``beamrelay serve --connect`` on the curve scenario; this process is the bus hub."""

    def __init__(self, tmp: Path) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.hub = open_session(listen=True, endpoint=self.endpoint)
        self.client = raw_session(self.endpoint)
        self.beats = Inbox(self.client, f"{PREFIX}/heartbeat")
        self.log = (tmp / "serve.log").open("wb")
        argv = [sys.executable, "-m", "planner.cli", "serve",
                str(shipped_scenario("curve_path.yaml")), "--connect", "--endpoint",
                self.endpoint, "--prefix", PREFIX]  # fmt: skip
        self.proc = subprocess.Popen(argv, stdout=self.log, stderr=subprocess.STDOUT,
                                     start_new_session=True)  # fmt: skip
        wait_for(lambda: len(self.beats.bodies()) > 10, 90.0, "heartbeats of serve")
        wait_for(lambda: len(heartbeat_children(self.proc.pid)) == 1, 10.0, "heartbeat child")
        self.child = heartbeat_children(self.proc.pid)[0]

    def close(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGCONT)
            self.proc.terminate()
            self.proc.wait(20)
        self.beats.close()
        self.client.close()
        self.hub.close()
        self.log.close()


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    s = Served(tmp_path_factory.mktemp("served"))
    yield s
    s.close()


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; -rR lists a rerun
def test_sigstop_silences_the_heartbeat_within_100ms(served: Served) -> None:
    time.sleep(0.3)
    os.kill(served.proc.pid, signal.SIGSTOP)
    t_stop = time.monotonic()
    time.sleep(0.6)
    last = served.beats.times()[-1]
    os.kill(served.proc.pid, signal.SIGCONT)
    t_cont = time.monotonic()
    wait_for(lambda: served.beats.times()[-1] > t_cont, 5.0, "beats after SIGCONT")
    print(f"last heartbeat {1e3 * (last - t_stop):.1f} ms after SIGSTOP")
    assert last - t_stop < 0.100
    assert not [t for t in served.beats.times() if last < t < t_cont]
    assert alive(served.child)  # the child waited; it did not exit


@pytest.mark.serial
@pytest.mark.flaky(reruns=1)  # real time on a shared machine; -rR lists a rerun
def test_heartbeat_keeps_its_rate_while_serve_plans_a_long_path(served: Served) -> None:
    """A curve path traced back and forth (about 900 samples at 1 mm): beats at 100 Hz
    throughout the plan (within 10 %), no gap the drivers would brake for (a real-time
    probe: the figures are printed)."""
    from planner.io.scenario import load_scenario

    targets = load_scenario(shipped_scenario("curve_path.yaml")).model.targets
    assert targets is not None and targets.path is not None
    curve = np.asarray(targets.path.points)
    there_and_back = np.concatenate([curve, curve[::-1][1:]])
    points = np.concatenate([there_and_back, there_and_back[1:], there_and_back[1:]])
    body = {"schema": "beamrelay.request/1", "id": "long", "mode": "path",
            "points": points.tolist()}  # fmt: skip
    t0 = time.monotonic()
    ok, reply = ask(served.client, f"{PREFIX}/plan", json.dumps(body).encode(), timeout=180)
    t1 = time.monotonic()
    plan = json.loads(reply)
    assert ok, plan
    times = np.asarray([t for t in served.beats.times() if t0 <= t <= t1])
    gaps = np.diff(times)
    print(f"plan of {len(plan['targets'])} path samples took {t1 - t0:.1f} s; heartbeat "
          f"{len(times) / (t1 - t0):.0f} Hz, gap p50 {1e3 * np.median(gaps):.1f} ms, "
          f"p99 {1e3 * np.percentile(gaps, 99):.1f} ms, max {1e3 * gaps.max():.1f} ms")  # fmt: skip
    assert len(plan["targets"]) > 800 and plan["metrics"]["n_ok"] > 800
    assert len(times) / (t1 - t0) >= 0.9 * HEARTBEAT_RATE
    assert np.median(gaps) <= 1.1 / HEARTBEAT_RATE
    assert gaps.max() < HEARTBEAT_TIMEOUT


@pytest.mark.serial
def test_sigkill_of_serve_takes_the_heartbeat_process_with_it(tmp_path: Path) -> None:
    s = Served(tmp_path)
    try:
        time.sleep(0.3)
        t_kill = time.monotonic()
        os.kill(s.proc.pid, signal.SIGKILL)
        s.proc.wait(10)
        wait_for(lambda: not alive(s.child), 5.0, "the heartbeat child to exit")
        t_gone = time.monotonic()
        time.sleep(0.3)
        last = s.beats.times()[-1]
        print(f"child gone {1e3 * (t_gone - t_kill):.0f} ms after SIGKILL, last beat "
              f"{1e3 * (last - t_kill):.1f} ms after it")  # fmt: skip
        assert last - t_kill < HEARTBEAT_TIMEOUT
    finally:
        s.close()


def test_child_config_is_a_client_of_the_planners_bus(tmp_path: Path) -> None:
    from planner.service.heartbeat import child_config

    def get(conf: Any, key: str) -> Any:
        return json.loads(conf.get_json(key))

    conf = child_config(BusAddress("tcp/127.0.0.1:7999"))
    assert get(conf, "mode") == "client"
    assert get(conf, "connect/endpoints") == ["tcp/127.0.0.1:7999"]
    assert get(conf, "listen/endpoints") == []
    # a config file of the bus host naming where it listens: the child connects there,
    # with the file's credentials (the planner's identity)
    (tmp_path / "host.json5").write_text(
        '{mode: "peer", listen: {endpoints: ["tcp/0.0.0.0:7998"]}, transport: {auth: '
        '{usrpwd: {user: "planner", password: "pw"}}}, '
        'access_control: {enabled: true, default_permission: "deny"}}'
    )
    conf = child_config(BusAddress(None, tmp_path / "host.json5"))
    assert get(conf, "mode") == "client"
    assert get(conf, "connect/endpoints") == ["tcp/127.0.0.1:7998"]
    assert get(conf, "listen/endpoints") == []
    assert get(conf, "transport/auth/usrpwd/user") == "planner"
    # only the host can apply an access list: in a client, default deny would cut it off
    assert get(conf, "access_control/enabled") is False


def test_a_heartbeat_process_that_cannot_reach_the_bus_fails_the_start() -> None:
    from planner.service.guard import Progress
    from planner.service.heartbeat import HeartbeatError, HeartbeatProcess

    hb = HeartbeatProcess(BusAddress("tcp/127.0.0.1:1"), "x/heartbeat", "s", Progress(),
                          lambda _: None, connect_timeout=1.0)  # fmt: skip
    with pytest.raises(HeartbeatError, match="the heartbeat process did not start"):
        hb.start(timeout=60.0)
    assert hb.proc is not None and hb.proc.poll() is not None


def test_the_heartbeat_travels_at_real_time_priority_from_a_raised_process() -> None:
    """Queued behind a 1 MB cloud frame a beat would miss the drivers' 100 ms: it is sent at
    Zenoh's real-time priority, unbatched, by a process under SCHED_FIFO (when root)."""
    import psutil
    import zenoh

    from planner.bus.priority import RT_PRIORITY

    system = system_with_camera()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_session(listen=True, endpoint=endpoint)
    seen: list[tuple[Any, bool]] = []
    sub = hub.declare_subscriber(
        f"{PREFIX}/heartbeat", lambda s: seen.append((s.priority, s.express))
    )
    node = PlannerNode(RequestHandler(system, make_plan_fn(system, {})), hub, Keys(PREFIX),
                       bus=BusAddress(endpoint)).start()  # fmt: skip
    try:
        wait_for(lambda: len(seen) >= 5, 30.0, "heartbeats")
        beater = [
            p
            for p in psutil.Process().children()
            if "planner.service.heartbeat" in " ".join(p.cmdline())
        ]
        policy = os.sched_getscheduler(beater[0].pid), os.sched_getparam(beater[0].pid)
    finally:
        node.close()
        sub.undeclare()
        hub.close()
    assert all(p == zenoh.Priority.REAL_TIME and express for p, express in seen), seen[:3]
    if os.geteuid() == 0:
        assert policy == (os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
