"""Motion of a scene object in the simulated world: its pose at time t.

A moving object's pose at time ``t`` (s) is ``world_T_object`` turned by
:meth:`ObjectMotion.rotation` about its own origin (world axes) and translated by
:meth:`ObjectMotion.offset` (m, world frame); a point ``x`` of the object at rest is at
``R(t) (x - origin) + origin + offset(t)`` (:meth:`ObjectMotion.move_points`). ``t`` is the simulation clock: UNIX time in the
running system, so every simulated process (camera, tracker) sees the same phase without
talking to the others. Kinds (``motion:`` in the scenario, :mod:`schemas.motion`):

- ``sine``: ``amplitude * sin(2 pi frequency t) * axis`` (axis a unit vector);
- ``linear``: a triangle wave of period ``2 duration``: ``velocity * tau`` for
  ``tau = t mod 2 duration`` below ``duration``, then back: ``velocity * (2 duration - tau)``;
- either with a turn: ``R(t)`` the rotation about the unit ``turn_axis`` by
  ``turn_amplitude * sin(2 pi turn_frequency t)`` (rad); none: ``R(t) = I``.

Planning ignores motion: it is simulation only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from planner.model.transforms import Array


@dataclass(frozen=True)
class ObjectMotion:
    """One object's motion. ``kind`` is ``sine`` (``direction`` = unit axis, ``amplitude``
    m, ``frequency`` Hz) or ``linear`` (``direction`` = velocity m/s, ``duration`` s)."""

    kind: str
    direction: Array
    amplitude: float = 0.0
    frequency: float = 0.0
    duration: float = 0.0
    turn_axis: Array | None = None  # unit, world
    turn_amplitude: float = 0.0  # rad
    turn_frequency: float = 0.0  # Hz

    @classmethod
    def sine(cls, axis: ArrayLike, amplitude: float, frequency: float) -> ObjectMotion:
        """A sine of ``amplitude`` m at ``frequency`` Hz along ``axis`` (normalised here)."""
        a = np.asarray(axis, dtype=float)
        return cls("sine", a / np.linalg.norm(a), float(amplitude), float(frequency))

    @classmethod
    def linear(cls, velocity: ArrayLike, duration: float) -> ObjectMotion:
        """``velocity`` m/s for ``duration`` s, then back, periodically."""
        return cls("linear", np.asarray(velocity, dtype=float), duration=float(duration))

    @property
    def period(self) -> float:
        """Period of the motion (s)."""
        return 1.0 / self.frequency if self.kind == "sine" else 2.0 * self.duration

    @property
    def peak_speed(self) -> float:
        """Largest speed of the motion (m/s)."""
        if self.kind == "sine":
            return 2 * np.pi * self.frequency * self.amplitude
        return float(np.linalg.norm(self.direction))

    @property
    def peak_acceleration(self) -> float:
        """Largest acceleration of the motion away from the linear turnarounds (m/s^2)."""
        if self.kind == "sine":
            return (2 * np.pi * self.frequency) ** 2 * self.amplitude
        return 0.0

    def with_turn(self, axis: ArrayLike, amplitude: float, frequency: float) -> ObjectMotion:
        """This motion plus a turn of ``amplitude`` rad at ``frequency`` Hz about ``axis``."""
        a = np.asarray(axis, dtype=float)
        return dataclasses.replace(self, turn_axis=a / np.linalg.norm(a),
                                   turn_amplitude=float(amplitude),
                                   turn_frequency=float(frequency))  # fmt: skip

    @property
    def turns(self) -> bool:
        return self.turn_axis is not None and self.turn_amplitude > 0.0

    def to_dict(self) -> dict[str, object]:
        """The scenario's ``motion:`` mapping of this motion (SI units, the turn in deg)."""
        if self.kind == "sine":
            out: dict[str, object] = {"kind": "sine", "axis": self.direction.tolist(),
                                      "amplitude": self.amplitude, "frequency": self.frequency}  # fmt: skip
        else:
            out = {"kind": "linear", "velocity": self.direction.tolist(), "duration": self.duration}
        if self.turn_axis is not None:
            out["turn"] = {"axis": self.turn_axis.tolist(),
                           "amplitude_deg": float(np.degrees(self.turn_amplitude)),
                           "frequency": self.turn_frequency}  # fmt: skip
        return out

    def rotation(self, t: float) -> Array:
        """The turn at time ``t`` (s): 3 x 3, world axes (the identity without a turn)."""
        if not self.turns:
            return np.eye(3)
        assert self.turn_axis is not None
        phase = np.mod(float(t), 1.0 / self.turn_frequency)  # UNIX times keep their digits
        angle = self.turn_amplitude * np.sin(2 * np.pi * self.turn_frequency * phase)
        k = self.turn_axis
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)

    def move_points(self, points: ArrayLike, origin: ArrayLike, t: float) -> Array:
        """Points (K x 3, world, m) of the object at rest moved to time ``t`` (s); ``origin``
        is the object's origin at rest (the centre of the turn)."""
        P, c = np.asarray(points, dtype=float), np.asarray(origin, dtype=float)
        return np.asarray((P - c) @ self.rotation(t).T + c + self.offset(t))

    def offset(self, t: ArrayLike) -> Array:
        """Translation (m, world frame) at time(s) ``t`` (s): shape (3,) or (K, 3)."""
        tt = np.asarray(t, dtype=float)
        if self.kind == "sine":
            w = 2 * np.pi * self.frequency
            s = self.amplitude * np.sin(w * np.mod(tt, self.period))
        else:
            tau = np.mod(tt, self.period)
            s = np.where(tau < self.duration, tau, self.period - tau)
        return np.multiply.outer(s, self.direction)

    def velocity(self, t: ArrayLike) -> Array:
        """Velocity (m/s, world frame) at time(s) ``t`` (s): shape (3,) or (K, 3)."""
        tt = np.asarray(t, dtype=float)
        if self.kind == "sine":
            w = 2 * np.pi * self.frequency
            s = self.amplitude * w * np.cos(w * np.mod(tt, self.period))
        else:
            s = np.where(np.mod(tt, self.period) < self.duration, 1.0, -1.0)
        return np.multiply.outer(s, self.direction)

    def pose(self, world_T_object: Array, t: float) -> Array:
        """``world_T_object`` moved to time ``t`` (s): 4x4."""
        T = np.array(world_T_object, dtype=float)
        T[:3, :3] = self.rotation(t) @ T[:3, :3]
        T[:3, 3] += self.offset(t)
        return T


def motion_from_schema(m: object) -> ObjectMotion:
    """The :class:`ObjectMotion` of a validated :class:`schemas.motion.Motion`."""
    kind = getattr(m, "kind", None)
    if kind == "sine":
        out = ObjectMotion.sine(m.axis, m.amplitude, m.frequency)  # type: ignore[attr-defined]
    elif kind == "linear":
        out = ObjectMotion.linear(m.velocity, m.duration)  # type: ignore[attr-defined]
    else:
        raise ValueError(f"unknown motion kind {kind!r}")
    turn = getattr(m, "turn", None)
    if turn is None:
        return out
    return out.with_turn(turn.axis, np.radians(turn.amplitude_deg), turn.frequency)
