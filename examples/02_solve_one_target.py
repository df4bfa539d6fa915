"""02: put the spot on one 3D target (world frame, metres) and verify it by a forward trace.

Run: python examples/02_solve_one_target.py
"""

from pathlib import Path

import numpy as np

import planner

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "paper_n1.yaml"
target = np.array([-0.49, -0.52, 0.0])

ik = planner.solver(SCENARIO)
sol = ik.solve(target)
print(f"status {sol.status}, spot error {1e3 * sol.error:.2e} mm, {1e3 * sol.solve_time:.2f} ms")
print(f"joints (rad): {np.round(sol.q, 4)}")

# independent of the solver: trace the beam at the returned joints
trace = planner.BeamModel(ik.system).trace(sol.q, target)
print(f"forward trace: error {1e3 * trace.error:.2e} mm, chain valid {trace.valid}")
