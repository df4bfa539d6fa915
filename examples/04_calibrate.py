"""04: simulate a hand-eye dataset (camera fixed in the world, board on the flange) with
D435-like depth noise, calibrate it, and compare with the truth used to simulate it.

Run: python examples/04_calibrate.py
"""

from pathlib import Path

import numpy as np

import planner
from planner.calibration.handeye import calibrate_handeye
from planner.calibration.simulate import DepthNoise, default_handeye_truth, simulate_handeye

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "paper_n1.yaml"

system = planner.load(SCENARIO).system
world_T_camera, flange_T_board = default_handeye_truth(system, "arm0", "eye_to_hand")
data = simulate_handeye(
    system, "arm0", "eye_to_hand", 20, camera_pose=world_T_camera, board_pose=flange_T_board,
    noise=DepthNoise(), rng=np.random.default_rng(0),
)  # fmt: skip
result = calibrate_handeye(data, system, loss="huber")
err = np.linalg.norm(result.camera_pose[:3, 3] - world_T_camera[:3, 3])
rms = np.sqrt(np.mean(result.point_residuals**2))
print(f"{len(data.q)} poses; camera position error {1e3 * err:.2f} mm (truth known)")
print(f"marker residual RMS {1e3 * rms:.2f} mm, converged: {result.converged}")
