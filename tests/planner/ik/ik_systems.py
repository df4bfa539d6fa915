"""Small systems built in code for the IK tests (no scenario files needed)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from planner.model.build import ur5e_robot
from planner.model.kinematics import RobotKinematics, ur5e_urdf_path
from planner.model.system import Limits, Robot, System
from planner.model.transforms import look_at, make_T, rot_z

LASER = look_at([0.6, -0.4, 0.3], [0.0, -0.4, 0.3])  # beam along -x, 0.4 m in front of arm0


def robot(name: str, base: np.ndarray | None = None, kin: RobotKinematics | None = None,
          limits: Limits | None = None, margin: float = 0.01) -> Robot:  # fmt: skip
    return ur5e_robot(name, base, roi_margin=margin, limits=limits, kinematics=kin)


def n1(laser: np.ndarray = LASER, **kw: object) -> System:
    return System(laser, (robot("arm0", **kw),))  # type: ignore[arg-type]


def n2() -> System:
    return System(LASER, (robot("arm0"), robot("arm1", make_T(rot_z(np.pi), [0.0, 1.0, 0.0]))))


def grid(center: list[float], half: float = 0.05, n: int = 3) -> np.ndarray:
    axis = np.linspace(-half, half, n)
    return np.stack(np.meshgrid(axis, axis, axis), -1).reshape(-1, 3) + center


def perturbed_urdf(tmp: Path, delta: float) -> Path:
    """The shipped UR5e URDF with every joint origin shifted by ``delta`` metres in x."""
    text = ur5e_urdf_path().read_text()

    def shift(m: re.Match[str]) -> str:
        x, y, z = (float(v) for v in m.group(1).split())
        return f'<origin xyz="{x + delta} {y} {z}"'

    out = re.sub(r'<origin xyz="([^"]+)"', shift, text)
    assert out != text
    path = tmp / "ur5e_calibrated.urdf"
    path.write_text(out)
    return path
