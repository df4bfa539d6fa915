"""What a robot backend (``sim``, ``ur``) offers the node: the per-period state and commands.

Joints in rad, rad/s, rad/s^2. :class:`drivers.robot.node.RobotNode` calls every method from
its control loop thread, once per period or between periods.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

from drivers.robot.follower import Reference, TrajectoryFollower
from planner.model.transforms import Array


class Measured(NamedTuple):
    """The arm's state after one period: joints (rad, rad/s) and controller state."""

    q: Array
    qd: Array
    mode: str
    protective_stop: bool = False
    fault: str | None = None
    stale: bool = False  # the link to the arm is stale: q, qd are old, not published
    safety: str | None = None  # the controller's safety mode (normal, reduced, ...)
    speed: float = 1.0  # the speed fraction the trajectory clock runs at (slider, pause)
    outputs: int | None = None  # the standard digital outputs read back (bit k = output k)


class RobotBackend(Protocol):
    """What :class:`RobotNode` needs from a backend (see ``drivers.robot.sim`` / ``drivers.robot.ur``)."""

    kind: str
    names: tuple[str, ...]
    rate: float
    follower: TrajectoryFollower

    def begin_period(self) -> None: ...
    def step(self) -> Measured: ...
    def end_period(self) -> None: ...
    def measured(self) -> Measured: ...
    def command(self, reference: Reference) -> None: ...
    def queue(self, reference: Reference) -> None: ...
    def start_stream(self) -> None:
        """A stream starts: InputError when the arm cannot follow one now."""

    def stream(self, q: Array, qd: Array, qdd: Array) -> None:
        """This period's streamed target state (see ``TrajectoryFollower.stream``)."""

    def brake(self, reason: str) -> None: ...
    def set_output(self, output: int, on: bool) -> None:
        """Switch standard digital output ``output`` (the laser gate or the aim beam); the
        UR backend writes it outside the control loop, with a timeout."""

    def close(self) -> None: ...
