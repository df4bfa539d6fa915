"""Closed-loop correction of the spot from camera measurements (pure: no bus, no drivers).

- :mod:`~planner.servo.jacobian`: the spot on a target's plane and d spot / dq through the
  beam graph (CasADi ``servo_spot``), :class:`SpotModel`;
- :mod:`~planner.servo.measure`: camera frames averaged into a world-frame
  :class:`SpotMeasurement`; the :class:`Measure` callback the loop calls;
- :mod:`~planner.servo.step`: one damped, bounded, checked correction step
  (:class:`Corrector`, :class:`ServoSettings`);
- :mod:`~planner.servo.loop`: :func:`servo` -> :class:`ServoResult` (:class:`ServoStatus`);
- :mod:`~planner.servo.ilc`: iterative learning control along a path (:func:`ilc_update`).
"""

from planner.servo.ilc import (
    IlcSettings,
    IlcUpdate,
    ilc_update,
    lowpass_along_arc,
    polyline_deviation,
)
from planner.servo.jacobian import SpotJacobian, SpotModel, spot_jacobian_function, surface_axes
from planner.servo.loop import ServoResult, ServoStatus, servo
from planner.servo.measure import Measure, SpotFrame, SpotMeasurement, average_frames
from planner.servo.step import Corrector, ServoSettings, Step, limit_failure

__all__ = [
    "Corrector",
    "IlcSettings",
    "IlcUpdate",
    "Measure",
    "ServoResult",
    "ServoSettings",
    "ServoStatus",
    "SpotFrame",
    "SpotJacobian",
    "SpotMeasurement",
    "SpotModel",
    "Step",
    "average_frames",
    "ilc_update",
    "limit_failure",
    "lowpass_along_arc",
    "polyline_deviation",
    "servo",
    "spot_jacobian_function",
    "surface_axes",
]
