"""The live part of ``make demo``: ``beamrelay up`` in the background, a few executed requests.

:func:`run_live_demo` starts ``beamrelay up SCENARIO`` (planner + simulated camera + one
simulated arm per robot) on a free loopback port, waits for every node's liveliness token,
then sends a few single-target requests with ``execute: true`` and prints, for each, the
spot the simulated camera measured and its distance to the target. Targets are points of
the scene's surfaces (the camera can only see the spot where the beam lands on something):
scenario targets spread over the set, each moved along its planned beam onto the scene.
Finally the loop keeps running for ``seconds`` s, and ``up`` is stopped with SIGTERM.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from planner.beam.trace import trace_beam
from planner.data import shipped_scenario
from planner.model.system import Targets
from planner.model.transforms import Array
from planner.service.client import PlanClient, RequestError, make_request


def free_endpoint() -> str:
    """``tcp/127.0.0.1:<port>`` with a port that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def surface_targets(scenario_path: Path, n: int) -> Array:
    """``n`` world points on the scene where the planned beams for ``n`` scenario targets
    (spread over the target set) land: each target moved along its own beam (metres)."""
    import open3d as o3d

    from drivers.camera.sim import build_scene
    from planner.io.scenario import (
        load_scenario,
        scene_objects,
        system_from_scenario,
        targets_from_scenario,
    )
    from planner.plan.scenario_planner import plan_points

    scn = load_scenario(scenario_path)
    system = system_from_scenario(scn)
    pts = targets_from_scenario(scn, system).points
    pick = pts[np.linspace(0, len(pts) - 1, 4 * n).astype(int)]
    scene = build_scene(scene_objects(scn))
    out = []
    for sol, p in zip(plan_points(system, Targets(pick)), pick, strict=True):
        if sol.q is None:
            continue
        ev = trace_beam(system, sol.q, p)
        ray = np.hstack([ev.hits[-1], ev.dirs[-1]]).astype(np.float32)[None]
        t = float(scene.cast_rays(o3d.core.Tensor.from_numpy(ray))["t_hit"].numpy()[0])
        if np.isfinite(t):
            out.append(ev.hits[-1] + t * ev.dirs[-1])
        if len(out) == n:
            break
    return np.array(out)


def run_live_demo(scenario_path: Path | str, seconds: float = 5.0, n_targets: int = 4) -> None:
    """Run the loop on ``scenario_path`` (needs a camera and a scene), print measured errors."""
    from rich.console import Console
    from rich.table import Table

    console = Console()
    scenario_path = Path(scenario_path).resolve()
    endpoint = free_endpoint()
    log_dir = Path(tempfile.mkdtemp(prefix="beamrelay-demo-"))
    argv = [sys.executable, "-m", "planner.cli", "up", str(scenario_path), "--endpoint", endpoint,
            "--no-live", "--log-dir", str(log_dir)]  # fmt: skip
    console.print(f"$ beamrelay up {scenario_path.name} --endpoint {endpoint}", style="dim")
    up = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        targets = surface_targets(scenario_path, n_targets)
        with PlanClient(endpoint=endpoint) as client:
            client.watch()
            with console.status("waiting for planner, camera and robot drivers..."):
                for node in ("planner", "camera", *_robot_names(scenario_path)):
                    if not client.wait_for_node(node, 60.0):
                        console.print(f"[red]{node} did not come up; logs in {log_dir}[/]")
                        return
            table = Table(title="live loop: executed requests (simulated camera)")
            for col in ("target x y z \\[m]", "measured x y z \\[m]", "error \\[mm]"):
                table.add_column(col)
            for p in targets:
                try:
                    _, spots = client.execute(make_request(p[None]), timeout=30.0)
                except RequestError as exc:
                    table.add_row(_fmt(p), f"[red]{exc}[/]", "-")
                    continue
                s = spots[0]
                err = "not seen" if s is None else f"{1e3 * np.linalg.norm(s - p):.2f}"
                table.add_row(_fmt(p), "-" if s is None else _fmt(s), err)
            console.print(table)
            console.print(f"loop running for {seconds:g} s more...")
            time.sleep(seconds)
    finally:
        up.send_signal(signal.SIGTERM)
        try:
            code = up.wait(15)
        except subprocess.TimeoutExpired:
            up.kill()
            code = up.wait()
        console.print(f"beamrelay up stopped (exit {code}); logs in {log_dir}")


def _robot_names(scenario_path: Path) -> list[str]:
    from planner.io.scenario import load_scenario

    return [r.name for r in load_scenario(scenario_path).model.system.robots]


def _fmt(p: Array) -> str:
    return " ".join(f"{x:+.4f}" for x in p)


if __name__ == "__main__":
    run_live_demo(Path(sys.argv[1]) if len(sys.argv) > 1 else shipped_scenario("paper_n1.yaml"))
