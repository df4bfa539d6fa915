"""``motion:`` of a scene object (simulation only): the object's pose moves in the world.

Two kinds, every length in metres, time in seconds:

- ``{kind: sine, axis: [x, y, z], amplitude: A, frequency: f}``: offset
  ``A sin(2 pi f t) * axis / |axis|`` (breathing: 5 mm at 0.25 Hz);
- ``{kind: linear, velocity: [vx, vy, vz], duration: T}``: offset ``v t`` for ``T`` s, then
  back at ``-v`` for ``T`` s, and so on (a triangle wave of period ``2 T``);
- either kind may also turn: ``turn: {axis: [x, y, z], amplitude_deg: a, frequency: f}``
  rotates the object about ``axis`` (world) through its own origin by ``a sin(2 pi f t)``
  degrees (a head turning side to side), on top of the translation.

Keys of the other kind are errors; implausible values name the likely unit mistake.
"""

from __future__ import annotations

import math
from typing import Literal, Self

from pydantic import model_validator

from schemas.common import FieldError, PosNum, StrictModel, Vec3

#: m: the largest sine amplitude / linear excursion accepted (beyond: millimetres?)
MAX_MOTION_M = 0.5
#: Hz: the fastest sine accepted (beyond: rad/s or rpm?)
MAX_FREQUENCY_HZ = 20.0
#: m/s: the fastest linear motion accepted (beyond: mm/s?)
MAX_VELOCITY_MPS = 2.0
#: s: the longest linear leg
MAX_DURATION_S = 3600.0
#: deg: the largest turn amplitude accepted (beyond: radians would be small, so degrees?)
MAX_TURN_DEG = 90.0
_KEYS = {"sine": ("axis", "amplitude", "frequency"), "linear": ("velocity", "duration")}


class Turn(StrictModel):
    """A sinusoidal turn about a world ``axis`` through the object's origin (degrees, Hz)."""

    axis: Vec3
    amplitude_deg: PosNum
    frequency: PosNum

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        if math.hypot(*self.axis) < 1e-9:
            raise FieldError(("axis",), "is zero: give the axis of the turn")
        if self.amplitude_deg > MAX_TURN_DEG:
            raise FieldError(("amplitude_deg",),
                             f"{self.amplitude_deg:g} deg is above {MAX_TURN_DEG:g} deg")  # fmt: skip
        if self.frequency > MAX_FREQUENCY_HZ:
            raise FieldError(("frequency",), f"{self.frequency:g} Hz is above "
                             f"{MAX_FREQUENCY_HZ:g} Hz: did you give rad/s? (Hz)")  # fmt: skip
        return self


class Motion(StrictModel):
    """A scene object's motion (see the module docstring); ``kind`` selects the keys."""

    kind: Literal["sine", "linear"]
    axis: Vec3 | None = None
    amplitude: PosNum | None = None
    frequency: PosNum | None = None
    velocity: Vec3 | None = None
    duration: PosNum | None = None
    turn: Turn | None = None

    @model_validator(mode="after")
    def _keys_of_kind(self) -> Self:
        wanted = _KEYS[self.kind]
        for other in (k for kind, keys in _KEYS.items() if kind != self.kind for k in keys):
            if getattr(self, other) is not None:
                raise FieldError(
                    (other,), f"not a key of kind {self.kind} (its keys: {', '.join(wanted)})"
                )
        for key in wanted:
            if getattr(self, key) is None:
                raise FieldError((key,), f"required for kind {self.kind}")
        if self.kind == "sine":
            self._check_sine()
        else:
            self._check_linear()
        return self

    def _check_sine(self) -> None:
        assert self.axis is not None and self.amplitude is not None and self.frequency is not None
        if math.hypot(*self.axis) < 1e-9:
            raise FieldError(("axis",), "is zero: give the direction of the motion")
        if self.amplitude > MAX_MOTION_M:
            raise FieldError(
                ("amplitude",),
                f"{self.amplitude:g} m is above {MAX_MOTION_M:g} m: did you give millimetres?"
                " (metres)",
            )
        if self.frequency > MAX_FREQUENCY_HZ:
            raise FieldError(
                ("frequency",),
                f"{self.frequency:g} Hz is above {MAX_FREQUENCY_HZ:g} Hz: did you give rad/s"
                " or per minute? (Hz)",
            )

    def _check_linear(self) -> None:
        assert self.velocity is not None and self.duration is not None
        speed = math.hypot(*self.velocity)
        if speed < 1e-12:
            raise FieldError(("velocity",), "is zero: give a velocity (m/s) or no motion")
        if speed > MAX_VELOCITY_MPS:
            raise FieldError(
                ("velocity",),
                f"{speed:g} m/s is above {MAX_VELOCITY_MPS:g} m/s: did you give mm/s? (m/s)",
            )
        if self.duration > MAX_DURATION_S:
            raise FieldError(("duration",), f"{self.duration:g} s is above {MAX_DURATION_S:g} s")
        if speed * self.duration > MAX_MOTION_M:
            raise FieldError(
                ("duration",),
                f"{speed:g} m/s for {self.duration:g} s moves {speed * self.duration:g} m,"
                f" above {MAX_MOTION_M:g} m: did you give milliseconds? (seconds)",
            )
