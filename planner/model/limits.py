"""Joint limits of one arm (position, velocity, acceleration, jerk), numpy arrays per joint.

Kept apart from :mod:`planner.model.system` so the independent checker can use it without
importing the planner's kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.model.transforms import Array
from schemas import defaults


@dataclass(frozen=True)
class Limits:
    """Joint limits per joint: position (rad), velocity (rad/s), acceleration, jerk."""

    lower: Array
    upper: Array
    velocity: Array
    acceleration: Array
    jerk: Array

    @staticmethod
    def ur_default(n: int = 6) -> Limits:
        """The conservative defaults of :mod:`schemas.defaults` for ``n`` joints: +-2 pi rad
        (a 6-joint UR's elbow +-pi), pi rad/s, 5 rad/s^2, 50 rad/s^3."""
        upper = np.full(n, defaults.JOINT_RANGE_RAD)
        if n == 6:
            upper[2] = defaults.ELBOW_RANGE_RAD
        return Limits(
            -upper,
            upper,
            np.full(n, defaults.JOINT_VELOCITY_RADPS),
            np.full(n, defaults.JOINT_ACCELERATION_RADPS2),
            np.full(n, defaults.JOINT_JERK_RADPS3),
        )
