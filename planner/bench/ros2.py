"""``beamrelay bench ros2``: does the ROS 2 bridge slow the drivers? In one run, a simulated
robot driver process hosts a private bus; its ``joint_states`` rate and period jitter are
measured on the bus for ``--seconds`` s without the bridge, then again while a
``beamrelay ros2 bridge`` process republishes them (whose ROS 2 JointState rate is measured
at the same time), then once more with the bridge stopped and the driver restarted with
``--ros2`` (its own topics from a thread and session inside the driver process). The period
statistics of the driver's samples, receiver side, include its control loop's jitter (the
sample is published from the loop) plus the bus's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from planner.bench.service import period_figures
from planner.errors import InputError

CLI = [sys.executable, "-m", "planner.cli"]
DOMAIN = 77  # a domain no lab is likely to use: the bench's topics stay out of real graphs
WARMUP = 60.0  # s allowed for the bridge to start and reach the bench's subscriber


def arrival_figures(stamps: list[float]) -> dict[str, float]:
    """Rate (Hz) and period statistics (ms) of arrival times (s)."""
    if len(stamps) < 3:
        raise RuntimeError(f"only {len(stamps)} samples arrived")
    return period_figures(np.diff(np.asarray(stamps, dtype=float)))


class Arrivals:
    """Arrival times (perf_counter s) per stream, thread safe."""

    def __init__(self) -> None:
        self.stamps: dict[str, list[float]] = {"bus": [], "ros": []}
        self._lock = threading.Lock()

    def on(self, name: str) -> Any:
        def cb(_sample: Any) -> None:
            now = time.perf_counter()
            with self._lock:
                self.stamps[name].append(now)

        return cb

    def window(self, seconds: float) -> dict[str, list[float]]:
        with self._lock:
            n0 = {k: len(v) for k, v in self.stamps.items()}
        time.sleep(seconds)
        with self._lock:
            return {k: list(v[n0[k] :]) for k, v in self.stamps.items()}

    def count(self, name: str) -> int:
        with self._lock:
            return len(self.stamps[name])


def measure(scenario: Path, seconds: float) -> dict[str, Any]:
    """The figures of the module docstring: ``off`` and ``on`` (bus joint_states) and
    ``ros2`` (the bridge's JointState)."""
    from planner.bench.service import _free_endpoint as free_endpoint
    from planner.bus.session import open_session

    endpoint = free_endpoint()
    prefix = "benchros"
    bus = ["--endpoint", endpoint, "--prefix", prefix]
    robot = _spawn(["driver", "robot", "--name", "arm0", "--listen", "--scenario",
                    str(scenario), *bus])  # fmt: skip
    bridge: subprocess.Popen[bytes] | None = None
    session = None
    arrivals = Arrivals()
    try:
        session = open_session(listen=False, endpoint=endpoint)
        subs = [
            session.declare_subscriber(f"{prefix}/arm0/joint_states", arrivals.on("bus")),
            session.declare_subscriber(f"{DOMAIN}/arm0/joint_states/**", arrivals.on("ros")),
        ]
        _wait(lambda: arrivals.count("bus") > 100, WARMUP, "the driver's joint states")
        off = arrivals.window(seconds)["bus"]
        bridge = _spawn(["ros2", "bridge", str(scenario), "--ros-domain", str(DOMAIN), *bus])
        _wait(lambda: arrivals.count("ros") > 100, WARMUP, "the bridge's joint states")
        on = arrival_figures_of(arrivals.window(seconds))
        for running in (bridge, robot):
            running.terminate()
            running.wait(30)
        bridge = None  # stopped: the driver runs its own
        robot = _spawn(["driver", "robot", "--name", "arm0", "--listen", "--scenario",
                        str(scenario), *bus, "--ros2", "--ros-domain", str(DOMAIN)])  # fmt: skip
        n_bus, n_ros = arrivals.count("bus"), arrivals.count("ros")
        _wait(lambda: arrivals.count("bus") > n_bus + 100 and arrivals.count("ros") > n_ros + 100,
              WARMUP, "the restarted driver's joint states, bus and ROS 2")  # fmt: skip
        inside = arrival_figures_of(arrivals.window(seconds))
        for s in subs:
            s.undeclare()
    finally:
        for p in (bridge, robot):
            if p is not None:
                p.terminate()
                p.wait(30)
        if session is not None:
            session.close()
    return {
        "seconds": seconds,
        "off": arrival_figures(off),
        "on": on["bus"],
        "ros2": on["ros"],
        "in_process": inside["bus"],
        "ros2_in_process": inside["ros"],
    }


def arrival_figures_of(window: dict[str, list[float]]) -> dict[str, dict[str, float]]:
    return {k: arrival_figures(v) for k, v in window.items()}


def _spawn(args: list[str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen([*CLI, *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=dict(os.environ))  # fmt: skip


def _wait(pred: Any, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.05)


def command(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML (robot arm0).")] = Path(
        "scenarios/paper_n1.yaml"
    ),
    seconds: Annotated[float, typer.Option(help="Measurement window each way, s.")] = 5.0,
    as_json: Annotated[bool, typer.Option("--json", help="Figures as JSON on the last line.")] = (
        False
    ),
) -> None:
    """joint_states rate and period jitter of a simulated driver with the ROS 2 bridge off,
    on, and inside the driver (--ros2), and the ROS 2 JointState rate of each."""
    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}")
    if not 0.5 <= seconds <= 600:
        raise InputError(f"--seconds {seconds:g}: expected 0.5-600 s")
    r = measure(scenario, seconds)
    for name, label in (("off", "bus, bridge off"), ("on", "bus, bridge on "),
                        ("ros2", "ROS 2 JointState"),
                        ("in_process", "bus, driver --ros2"),
                        ("ros2_in_process", "ROS 2 JointState, driver --ros2")):  # fmt: skip
        f = r[name]
        typer.echo(
            f"{label}: {f['rate_hz']:.1f} Hz, period median {f['period_median_ms']:.2f} ms, "
            f"jitter std {f['jitter_std_ms']:.3f} ms, p99 {f['period_p99_ms']:.2f} ms, max "
            f"{f['period_max_ms']:.2f} ms"
        )
    if as_json:
        print(json.dumps(r))
