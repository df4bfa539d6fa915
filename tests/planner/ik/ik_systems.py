"""Small systems built in code for the IK tests (no scenario files needed)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from planner.model.kinematics import RobotKinematics, ur5e_urdf_path
from planner.model.system import DEFAULT_HOME, Limits, Mirror, Robot, System
from planner.model.transforms import look_at, make_T, rot_z

LASER = look_at([0.6, -0.4, 0.3], [0.0, -0.4, 0.3])  # beam along -x, 0.4 m in front of arm0


def robot(name: str, base: np.ndarray | None = None, kin: RobotKinematics | None = None,
          limits: Limits | None = None, margin: float = 0.01) -> Robot:  # fmt: skip
    return Robot(
        name,
        kin or RobotKinematics.ur5e(),
        np.eye(4) if base is None else base,
        Mirror(make_T(p=[0, 0, 0.03]), (0.075, 0.075), margin),
        np.array(DEFAULT_HOME),
        limits or Limits.ur_default(),
    )


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
