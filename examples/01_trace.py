"""01: trace the beam forward at the robots' home joints.

Run: python examples/01_trace.py   (seconds; no hardware, no bus)
"""

from pathlib import Path

import planner

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "paper_n1.yaml"

setup = planner.load(SCENARIO)
trace = planner.BeamModel(setup.system).trace(setup.system.home)
for robot, hit, uv in zip(setup.system.robot_names, trace.hits, trace.uv, strict=True):
    print(f"{robot}: hit {hit.round(4)} m, (u, v) = {(1e3 * uv).round(2)} mm on the mirror")
print(f"outgoing direction {trace.dirs[-1].round(4)}; chain valid: {trace.valid}")
