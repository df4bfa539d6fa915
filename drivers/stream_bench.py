"""Control-loop timing of a robot driver while it follows a 500 Hz setpoint stream.

:func:`stream_jitter` runs a :class:`drivers.robot.node.RobotNode` with the 500 Hz
:class:`drivers.robot.sim.SimRobot` on a private loopback bus (``require_planner`` off),
records the start time of every control period for ``quiet`` seconds, then for
``seconds`` from the first setpoint received while another process streams setpoints through
:class:`planner.service.setpoints.SetpointStreamer` (a small sine on every joint from the
arm's home, 0.05 rad at 0.5 Hz), optionally with ``garbage`` bodies per second on the same
key (each ends the stream: the sender's next setpoints are ignored until it pauses, so only
the loop figures are meaningful then). Reports :class:`drivers.bench.LoopStats` for both
windows, the setpoints sent and received, the bodies rejected and the stream's final
verdict (a stream that went stale on a loaded machine braked the arm).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from drivers.bench import _free_port, loop_stats, node_window
from planner.bus.session import Keys, open_session
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits

SENDER = """
import math, os, sys, time
import numpy as np
from drivers.bench import peer_session
from planner.bus.session import Keys
from planner.service.setpoints import SetpointStreamer
from planner.model.system import DEFAULT_HOME
os.nice(5)
endpoint, prefix, seconds, garbage = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
s = peer_session(endpoint)
home, start = np.array(DEFAULT_HOME), time.time()
w = 2 * math.pi * 0.5
def ref(t):
    x = t - start
    c, sn = math.cos(w * x), math.sin(w * x)
    return {"arm0": (home + 0.05 * (1 - c) ** 2 / 4, np.full(6, 0.05 * (1 - c) * w * sn / 2))}, False
pub = s.declare_publisher(f"{prefix}/arm0/setpoint")
with SetpointStreamer(s, Keys(prefix), "bench", ["arm0"], reference=ref, request_id="bench") as st:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if garbage > 0:
            pub.put(b'{"schema": "beamrelay.setpoint/1", "q": [NaN]}')
        time.sleep(1 / garbage if garbage > 0 else 0.05)
    print(st.seq, flush=True)
"""


def stream_jitter(seconds: float = 5.0, quiet: float = 2.0, garbage: float = 0.0) -> dict[str, Any]:
    """Loop figures without and with the stream (see the module docstring)."""

    from drivers.robot.node import RobotNode
    from drivers.robot.sim import SimRobot

    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    keys, limits = Keys("sbench"), Limits.ur_default()
    session = open_session(listen=True, endpoint=endpoint)
    robot = SimRobot(JOINT_NAMES_UR, np.array(DEFAULT_HOME), limits)
    node = RobotNode(session, keys, "arm0", robot, limits, require_planner=False).start()
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]))
    args = [endpoint, keys.prefix, str(seconds), str(garbage)]
    try:
        time.sleep(1.0)
        n0 = node.n_periods
        time.sleep(quiet)
        n1 = node.n_periods
        proc = subprocess.Popen([sys.executable, "-c", SENDER, *args], stdout=subprocess.PIPE,
                                env=env)  # fmt: skip
        end = time.monotonic() + seconds + 60
        while node.setpoints.n_received == 0 and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.001)
        n1 = node.n_periods  # from the first setpoint on
        out, _ = proc.communicate(timeout=seconds + 60)
        n2 = node.n_periods
        time.sleep(0.2)
    finally:
        node.stop()
        session.close()
    ack = node.streams.status()
    dt = 1.0 / robot.rate
    return {
        "quiet": loop_stats(node_window(node, n0, n1), dt),
        "streaming": loop_stats(node_window(node, n1, n2), dt),
        "sent": int(out.split()[-1]),
        "received": node.setpoints.n_received,
        "rejected": node.setpoints.n_rejected,
        "stream": None if ack is None else ack.model_dump(),
    }
