"""Control-loop timing of a robot driver, quiet and under a trajectory flood.

:func:`flood_jitter` runs a :class:`drivers.robot.node.RobotNode` with the 500 Hz
:class:`drivers.robot.sim.SimRobot` (``backend="sim"``) or the UR backend
(:class:`drivers.robot.ur.URRobot`) on the simulated controller
(:class:`drivers.robot.ur_fake.FakeURController`, paced by ``waitPeriod`` like ur_rtde's),
optionally with ``realtime`` (SCHED_FIFO for the control loop, when permitted), on a
private loopback bus, records the start time of
every control period (monotonic clock) for ``quiet`` seconds, then for ``seconds`` while a
plain Zenoh publisher in another process sends ``samples``-sample trajectories (``rate`` per second, ~3.5 MB
each at 8900 samples) that the driver parses and checks in full and then rejects (they
start 0.05 rad away from the arm), and reports :class:`LoopStats` for both windows.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from drivers.robot.ur_fake import FakeURController
from planner.bus.session import Keys, open_session
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from planner.model.transforms import Array
from schemas import defaults


class LoopStats(NamedTuple):
    """Control period figures (ms): median, 99th percentile and largest period, and the
    largest lateness of a period start behind the ideal grid ``t0 + n dt``."""

    periods: int
    p50_ms: float
    p99_ms: float
    max_ms: float
    max_late_ms: float

    def line(self) -> str:
        return (
            f"{self.periods} periods: p50 {self.p50_ms:.3f} ms, p99 {self.p99_ms:.3f} ms, "
            f"max {self.max_ms:.3f} ms, max lateness {self.max_late_ms:.3f} ms"
        )


def loop_stats(starts: Array, dt: float) -> LoopStats:
    """Figures of a run of consecutive period start times ``starts`` (s) at period ``dt``."""
    starts = np.asarray(starts, dtype=float)
    if len(starts) < 3:
        raise ValueError(f"need at least 3 period starts, got {len(starts)}")
    p = np.diff(starts)
    late = starts - (starts[0] + dt * np.arange(len(starts)))
    return LoopStats(
        len(p),
        float(1e3 * np.median(p)),
        float(1e3 * np.quantile(p, 0.99)),
        float(1e3 * p.max()),
        float(1e3 * (late.max() - late.min())),
    )


def node_window(node: Any, n0: int, n1: int) -> Array:
    """Period start times ``n0 <= n < n1`` from the node's ring buffer."""
    from drivers.robot.node import PERIOD_LOG

    if n1 - n0 > PERIOD_LOG:
        raise ValueError(f"window of {n1 - n0} periods exceeds the {PERIOD_LOG} kept")
    idx = np.arange(n0, n1) % PERIOD_LOG
    return np.asarray(node.period_starts[idx])


def flood_body(
    samples: int, q0: Array, names: list[str], rate: float = defaults.SERVO_RATE_HZ
) -> bytes:
    """A valid-looking ``samples``-sample trajectory body (a slow minimum-jerk move)."""

    t = np.arange(samples) / rate
    x = t / t[-1]
    s = 10 * x**3 - 15 * x**4 + 6 * x**5
    dq = np.full(len(q0), 0.2)
    q = q0 + s[:, None] * dq
    qd = ((30 * x**2 - 60 * x**3 + 30 * x**4) / t[-1])[:, None] * dq
    qdd = ((60 * x - 180 * x**2 + 120 * x**3) / t[-1] ** 2)[:, None] * dq
    body = {"schema": "beamrelay.trajectory/1", "robot": "arm0", "id": "flood", "t": t.tolist(),
            "names": names, "q": q.tolist(), "qd": qd.tolist(), "qdd": qdd.tolist()}  # fmt: skip
    return json.dumps(body).encode()


def flood_jitter(
    seconds: float = 5.0,
    samples: int = 8900,
    rate: float = 10.0,
    quiet: float = 3.0,
    backend: str = "sim",
    realtime: bool = False,
) -> dict[str, Any]:
    """Loop figures without and with the flood (see the module docstring), and the counts of
    trajectories sent, checked (a verdict) and superseded before they were checked."""
    from drivers.robot.node import RobotNode
    from drivers.robot.sim import SimRobot

    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    keys, limits, home = Keys("bench"), Limits.ur_default(), np.array(DEFAULT_HOME)
    session = open_session(listen=True, endpoint=endpoint)  # the driver hosts the bus
    robot: Any
    fake: Any = None
    if backend == "ur":
        from drivers.robot.ur import URRobot

        fake = FakeURController(home, realtime=True, lag=False)
        robot = URRobot("bench", JOINT_NAMES_UR, limits, robot="arm0", control=fake,
                        receive=fake, realtime=realtime)  # fmt: skip
    else:
        robot = SimRobot(JOINT_NAMES_UR, home, limits)
    node = RobotNode(session, keys, "arm0", robot, limits, require_planner=False).start()
    sent, size = 0, 0
    try:
        time.sleep(1.0)  # connect, settle
        n0 = node.n_periods
        time.sleep(quiet)
        n1 = node.n_periods
        sent, size = _flood(endpoint, keys.trajectory("arm0"), samples, rate, seconds)
        n2 = node.n_periods
        end = time.monotonic() + 30.0
        while not node.intake.idle and time.monotonic() < end:
            time.sleep(0.05)
        time.sleep(0.1)
    finally:
        node.stop()
        session.close()
    dt = 1.0 / robot.rate
    return {
        "quiet": loop_stats(node_window(node, n0, n1), dt),
        "flood": loop_stats(node_window(node, n1, n2), dt),
        "sent": sent,
        "bytes": size,
        "checked": node.n_accepted + node.n_rejected - node.intake.n_superseded,
        "superseded": node.intake.n_superseded,
        "backend": backend,
        "watchdog_trips": None if fake is None else fake.watchdog_trips,
    }


def peer_session(endpoint: str, settle: float = 0.5) -> Any:
    """A plain Zenoh peer session connected to ``endpoint`` (no multicast scouting), ``settle``
    s after opening (for the connection): the load generators' side of a bench, run in their
    own process."""

    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    session = zenoh.open(conf)
    time.sleep(settle)
    return session


FLOOD = """
import os, sys, time
from drivers.bench import flood_body, peer_session
os.nice(10)  # the load generator, not the system under test
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR
endpoint, key, samples, rate, seconds = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5])
s = peer_session(endpoint)
body = flood_body(samples, [q + 0.05 for q in DEFAULT_HOME], list(JOINT_NAMES_UR))
pub = s.declare_publisher(key)
sent, start = 0, time.monotonic()
while time.monotonic() - start < seconds:
    pub.put(body)
    sent += 1
    time.sleep(max(0.0, start + sent / rate - time.monotonic()))
time.sleep(0.2)
print(sent, len(body), flush=True)
"""


def _flood(endpoint: str, key: str, samples: int, rate: float, seconds: float) -> tuple[int, int]:
    """Run the flood from a separate process (plain Zenoh publisher), so the figures are the
    driver's alone; (bodies sent, bytes per body)."""

    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]))
    args = [endpoint, key, str(samples), str(rate), str(seconds)]
    out = subprocess.run([sys.executable, "-c", FLOOD, *args], capture_output=True, env=env,
                         timeout=seconds + 60, check=True)  # fmt: skip
    sent, size = out.stdout.split()
    return int(sent), int(size)


def _free_port() -> int:

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
