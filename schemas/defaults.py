"""The default of every optional setting, defined once (SI units).

The schemas use these for keys a file leaves out; the planner, the checker and the drivers
import the same names instead of repeating the numbers.
"""

from __future__ import annotations

import math

# --- trajectory -----------------------------------------------------------------------------
SERVO_RATE_HZ = 500.0
"""Trajectory sample rate and robot control rate, Hz (``trajectory.rate``; the UR e-Series
servo rate, one sample per 2 ms controller cycle)."""
SERVOJ_LOOKAHEAD_S = 0.1
"""The UR driver's servoJ ``lookahead_time``, s (URScript accepts 0.03-0.2); also the lag of
the simulated arm's servo model (:mod:`drivers.robot.servo_lag`)."""
SERVOJ_GAIN = 300.0
"""The UR driver's servoJ ``gain`` (URScript accepts 100-2000; 300 is its default)."""
HEARTBEAT_RATE_HZ = 100.0
"""The planner's heartbeat rate, Hz (the drivers brake after 100 ms of silence)."""
SPOT_SPEED_MPS = 0.02
"""Speed of the spot along a path, m/s (``trajectory.spot_speed``)."""
DWELL_S = 0.0
"""Time the spot rests on each point/grid target, s (``trajectory.dwell``)."""
PATH_TOLERANCE_M = 5e-5
"""Largest distance of the spot from the path while the laser is on, m
(``trajectory.path_tolerance``)."""

# --- targets and solver ---------------------------------------------------------------------
PATH_SPACING_M = 0.001
"""Distance between consecutive samples of a path target, m (``targets.path.spacing``)."""
SPOT_TOLERANCE_M = 1e-9
"""Spot error a solved target may have, m (``solver.tolerance``)."""
SOLVER_MAX_ITER = 200
"""Iteration limit of the IPOPT solves (``solver.max_iter``)."""
MAX_INCIDENCE_DEG = 80.0
"""Largest angle between the arriving beam and a target's normal, degrees
(``solver.max_incidence_deg``)."""

# --- robots ---------------------------------------------------------------------------------
ROI_MARGIN_M = 0.005
"""Distance the beam keeps from a mirror's edges, m (``mirror.roi_margin``)."""
JOINT_RANGE_RAD = 2 * math.pi
"""Position limit +- of every joint except a UR elbow, rad (``limits.lower/upper``)."""
ELBOW_RANGE_RAD = math.pi
"""Position limit +- of a UR elbow (joint 3), rad."""
JOINT_VELOCITY_RADPS = math.pi
"""Joint velocity limit, rad/s (UR datasheet; ``limits.velocity``)."""
JOINT_ACCELERATION_RADPS2 = 5.0
"""Joint acceleration limit, rad/s^2 (conservative for work near people)."""
JOINT_JERK_RADPS3 = 50.0
"""Joint jerk limit, rad/s^3 (conservative for work near people)."""

# --- closed loop ----------------------------------------------------------------------------
SERVO_TOLERANCE_M = 3e-4
"""Measured spot error a closed-loop target is corrected to, m (a request's ``tolerance``)."""
SERVO_FRAMES = 3
"""Camera frames averaged per closed-loop spot measurement."""
SERVO_FIRST_FRAMES = 1
"""Camera frames of a closed-loop target's first (open-loop) measurement: its error is large,
one frame's noise (~0.2 mm for a D435 at 0.9 m) does not matter for the first correction."""
SERVO_MAX_ITERATIONS = 6
"""Correction steps per closed-loop target at most."""
SERVO_MAX_STEP_RAD = 0.02
"""Largest change of any joint in one closed-loop correction step, rad."""

# --- camera-frame targets -------------------------------------------------------------------
SURFACE_TOLERANCE_M = 0.015
"""Least distance a camera-frame target may lie from the scene surface that carries it, m:
mapped through the calibrated camera pose it is off by the camera's calibration error; the
plan lands it on that surface (the tolerance grows to 3 x the calibration's spot uncertainty
when that is larger)."""
