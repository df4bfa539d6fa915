"""Checks a robot driver applies to streamed joint setpoints (``<prefix>/<robot>/setpoint``).

A setpoint (:class:`schemas.messages.Setpoint`) is small (~300 bytes) and comes at up to
500 Hz, so it is parsed in the Zenoh callback thread, on a cheap path: ``json.loads`` and
pydantic's JSON parser on the schema (~40 us; the project's untrusted-body reader with
located errors takes ~130 us), and only a body it refuses goes through
:func:`planner.bus.session.decode` for an error that names the field. Joints in
rad, rad/s, rad/s^2; ``t`` in the sender's seconds; ``received`` on the driver's monotonic
clock. Every failed check raises :class:`planner.errors.InputError` whose ``where`` names the
field and whose reason gives the joint and the figure against its limit.

1. :func:`parse_setpoint`: size (at most :data:`MAX_SETPOINT_BYTES`), schema, robot name,
   one value per joint, every position inside the position limits, every velocity ``qd``
   inside the velocity limit;
2. :func:`check_next`, against the previous setpoint of the same stream: ``t`` and ``seq``
   increase; the positions move at most the velocity limit over the time step
   (``|q_k - q_k-1| / (t_k - t_k-1)``); the velocities change at most the acceleration
   limit over it (``|qd_k - qd_k-1| / (t_k - t_k-1)``), which is also the acceleration the
   follower aims at (``qdd`` of the returned sample);
3. :func:`check_stream_start`: the first setpoint of a stream lies within
   :data:`START_POSITION_TOLERANCE` rad and :data:`START_VELOCITY_TOLERANCE` rad/s of the
   arm's commanded state on every joint.

Slack as for trajectories (:mod:`drivers.robot.trajectory_check`): a relative
:data:`~drivers.robot.trajectory_check.LIMIT_SLACK` on the limits plus what a position
rounding of :data:`~drivers.robot.trajectory_check.POSITION_NOISE` rad adds to a difference.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from pydantic import ValidationError

from drivers.robot.trajectory_check import LIMIT_SLACK, POSITION_NOISE, START_TOLERANCE
from planner.bus.session import decode
from planner.errors import InputError
from planner.model.system import Limits
from planner.model.transforms import Array
from schemas.messages import Setpoint

MAX_SETPOINT_BYTES = 16 * 1024  # a 6-joint setpoint is ~300 bytes
STALE_AFTER = 0.050  # s without a new setpoint (receive clock): the stream is stale
START_POSITION_TOLERANCE = START_TOLERANCE  # rad: first setpoint vs the commanded state
START_VELOCITY_TOLERANCE = 0.1  # rad/s: first setpoint's qd vs the commanded velocity


class SetpointSample(NamedTuple):
    """One setpoint that passed :func:`parse_setpoint`: ``received`` (monotonic s, driver),
    ``t`` (s, sender's clock), stream ``session``/``id``, ``seq``, ``q`` (rad), ``qd``
    (rad/s), ``laser_on``, ``aim``; ``qdd`` (rad/s^2) the acceleration since the stream's previous
    setpoint (zero for a stream's first, set by :func:`check_next`)."""

    received: float
    t: float
    session: str
    seq: int
    id: str | None
    q: Array
    qd: Array
    laser_on: bool
    qdd: Array | None = None
    aim: bool = False

    @property
    def key(self) -> tuple[str, str | None]:
        """What identifies the stream: (session, id)."""
        return (self.session, self.id)


def _validate(body: bytes) -> Setpoint:
    """The schema's verdict: pydantic's own JSON parser first (~40 us); a body it refuses goes
    through :func:`planner.bus.session.decode` for an error that names the field."""

    try:
        return Setpoint.model_validate_json(body)
    except (ValidationError, ValueError, ArithmeticError):
        pass

    return decode(body, Setpoint)  # raises InputError (else: the same message)


def parse_setpoint(
    body: bytes, received: float, robot: str, names: tuple[str, ...], limits: Limits
) -> SetpointSample:
    """Check 1 of the module docstring; the sample, or InputError."""
    if len(body) > MAX_SETPOINT_BYTES:
        raise InputError(f"payload of {len(body)} bytes exceeds {MAX_SETPOINT_BYTES} bytes", "body")
    msg = _validate(body)
    if msg.robot != robot:
        raise InputError(f"setpoint is for robot {msg.robot!r}, this driver is {robot!r}", "robot")
    if len(msg.q) != len(names):
        raise InputError(f"expected {len(names)} numbers (one per joint), got {len(msg.q)}", "q")
    q = np.array(msg.q, dtype=float)
    qd = np.array(msg.qd, dtype=float)
    _check_bounds(q, qd, names, limits)
    return SetpointSample(
        received, msg.t, msg.session, msg.seq, msg.id, q, qd, msg.laser_on, aim=msg.aim
    )  # fmt: skip


def _check_bounds(q: Array, qd: Array, names: tuple[str, ...], lim: Limits) -> None:
    vmax = lim.velocity * (1 + LIMIT_SLACK)
    if not ((q < lim.lower) | (q > lim.upper) | (np.abs(qd) > vmax)).any():
        return  # the common case: one test
    rules = [
        ("q", q, q < lim.lower, lim.lower, "below lower limit", "rad"),
        ("q", q, q > lim.upper, lim.upper, "above upper limit", "rad"),
        ("qd", qd, np.abs(qd) > vmax, lim.velocity, "exceeds", "rad/s"),
    ]
    for key, x, bad, bound, what, unit in rules:
        if bad.any():
            j = int(np.argmax(bad))
            raise InputError(
                f"{x[j]:.4f} {unit} on joint {names[j]} {what} {bound[j]:.4f} {unit}", key
            )


def check_next(
    prev: SetpointSample, new: SetpointSample, names: tuple[str, ...], limits: Limits
) -> SetpointSample:
    """Check 2 of the module docstring; ``new`` with its acceleration ``qdd``, or InputError."""
    if new.seq <= prev.seq:
        raise InputError(f"{new.seq} does not follow {prev.seq} (seq must increase)", "seq")
    dt = new.t - prev.t
    if not dt > 0:
        raise InputError(f"{new.t:.6f} s is not after the previous setpoint's {prev.t:.6f} s", "t")
    dq = new.q - prev.q
    v = np.abs(dq) / dt
    bad = v > limits.velocity * (1 + LIMIT_SLACK) + 2 * POSITION_NOISE / dt
    if bad.any():
        j = int(np.argmax(bad))
        raise InputError(
            f"{names[j]} moves {abs(dq[j]):.4f} rad in {dt:.4f} s since seq {prev.seq} = "
            f"{v[j]:.1f} rad/s > {limits.velocity[j]:.4f} rad/s",
            "q",
        )
    qdd = (new.qd - prev.qd) / dt
    bad = np.abs(qdd) > limits.acceleration * (1 + LIMIT_SLACK)
    if bad.any():
        j = int(np.argmax(bad))
        raise InputError(
            f"{names[j]} velocity changes {abs(qdd[j] * dt):.4f} rad/s in {dt:.4f} s since "
            f"seq {prev.seq} = {abs(qdd[j]):.1f} rad/s^2 > {limits.acceleration[j]:.4f} rad/s^2",
            "qd",
        )
    return new._replace(qdd=qdd)


def check_stream_start(
    first: SetpointSample,
    q_now: Array,
    qd_now: Array,
    names: tuple[str, ...],
    q_tolerance: float = START_POSITION_TOLERANCE,
    qd_tolerance: float = START_VELOCITY_TOLERANCE,
) -> None:
    """Check 3 of the module docstring (InputError with the figures if not)."""
    for key, got, now, tol, unit in (
        ("q", first.q, q_now, q_tolerance, "rad"),
        ("qd", first.qd, qd_now, qd_tolerance, "rad/s"),
    ):
        gap = np.abs(got - np.asarray(now, dtype=float))
        if np.max(gap) > tol:
            j = int(np.argmax(gap))
            raise InputError(
                f"stream starts {gap[j]:.4f} {unit} from the current state on joint "
                f"{names[j]} (tolerance {tol:g} {unit})",
                key,
            )
