"""The control-loop side of setpoint streams: which stream is followed, and where to.

:class:`StreamControl` holds the stream the arm follows (:class:`ActiveStream`) and the
verdict the status carries (:class:`schemas.messages.StreamAck`). It is pure (no Zenoh, no
clock: every call gets ``now``, monotonic s); :class:`drivers.robot.node.RobotNode` calls it
once per control period with the events of :class:`drivers.robot.setpoint_intake.SetpointIntake`
and decides admission and safety stops.

Where the arm is driven. A setpoint says which state (q, qd) the arm should have at its
``t``. The sender's clock is mapped onto the driver's receive clock by the smallest
``received - t`` seen in the stream (the transport delay at its least, so jitter in
delivery does not move the target and clocks of different hosts need not agree): a setpoint
applies when it arrives (at the least delay), and the arm is on it at the end of the period
that received it (one period, 2 ms, behind the stream). Without a newer setpoint the target
moves on from the newest one along its velocity and its acceleration ``qdd`` (from the last
two setpoints' velocities): ``q = q_k + qd_k h + qdd_k h^2 / 2``, ``qd = qd_k + qdd_k h``,
``h`` the time since the setpoint applied, at most :data:`MAX_EXTRAPOLATION` (twice the
50 ms after which the stream is stale, so the bound never binds on a followed stream),
positions clamped to the limits. The follower's Ruckig step takes the arm there within the
velocity, acceleration and jerk limits. A stream that the jerk limit can follow from the
arm's state is played exactly; one that it cannot (a step in acceleration, noisy ``qd``)
is chased time-optimally toward each period's target, which lags and overshoots a moving
target by millimetres of joint motion for a second or more: stream smooth references.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from drivers.robot.setpoint_check import STALE_AFTER, SetpointSample
from planner.model.system import Limits
from planner.model.transforms import Array
from schemas.messages import StreamAck

MAX_EXTRAPOLATION = 2 * STALE_AFTER  # s: longest time the target moves on from a setpoint


@dataclass
class ActiveStream:
    """The stream followed: its number in the intake, newest setpoint, the clock offset
    (s: receive clock minus the sender's time since the first setpoint ``t0``, smallest
    seen; relative times keep the sub-microsecond resolution a UNIX ``t`` lacks) and the
    number of setpoints followed."""

    stream: int
    latest: SetpointSample
    t0: float
    offset: float
    n: int = 1

    @property
    def session(self) -> str:
        return self.latest.session

    @property
    def id(self) -> str | None:
        return self.latest.id


class StreamControl:
    """Loop-side stream state for one arm (see the module docstring)."""

    def __init__(self, limits: Limits, dt: float, stale_after: float = STALE_AFTER) -> None:
        self.limits, self.dt, self.stale_after = limits, dt, stale_after
        self.active: ActiveStream | None = None
        self.ack: StreamAck | None = None
        self.n_streams = 0

    def begin(self, stream: int, first: SetpointSample) -> None:
        """Follow stream number ``stream`` from its first setpoint (admitted by the node)."""
        self.active = ActiveStream(stream, first, first.t, first.received)
        self.n_streams += 1
        self._set("streaming", None, False)

    def advance(self, stream: int, sample: SetpointSample) -> bool:
        """The stream's newest checked setpoint; False if ``stream`` is not followed."""
        a = self.active
        if a is None or a.stream != stream:
            return False
        a.latest = sample
        a.offset = min(a.offset, sample.received - (sample.t - a.t0))
        a.n += 1
        return True

    def follows(self, stream: int) -> bool:
        return self.active is not None and self.active.stream == stream

    def silent(self, now: float) -> float:
        """Time (s) since the followed stream's newest setpoint arrived (0 when none)."""
        return 0.0 if self.active is None else now - self.active.latest.received

    def stale(self, now: float) -> bool:
        return self.active is not None and self.silent(now) > self.stale_after

    @property
    def laser_on(self) -> bool:
        """The newest setpoint's ``laser_on`` while a stream is followed, else False."""
        return self.active is not None and self.active.latest.laser_on

    @property
    def aim(self) -> bool:
        """The newest setpoint's ``aim`` while a stream is followed, else False."""
        return self.active is not None and self.active.latest.aim

    def target(self, now: float) -> tuple[Array, Array, Array]:
        """(q, qd, qdd) the arm should have at the end of this period (started at ``now``)."""
        a = self.active
        assert a is not None
        s = a.latest
        qdd = s.qdd if s.qdd is not None else np.zeros_like(s.qd)
        h = min(max(now - (s.t - a.t0 + a.offset), 0.0), MAX_EXTRAPOLATION)
        q = np.clip(s.q + s.qd * h + 0.5 * qdd * h * h, self.limits.lower, self.limits.upper)
        return q, s.qd + qdd * h, qdd

    def end(self, reason: str, braked: bool, rejected: bool = False) -> int | None:
        """Stop following; the stream's number (None when none was followed)."""
        a = self.active
        if a is None:
            return None
        self._set("rejected" if rejected else "ended", reason, braked)
        self.active = None
        return a.stream

    def refuse(self, sample: SetpointSample | None, reason: str) -> None:
        """A stream that does not start (``sample`` its first setpoint), or a body on the
        key that did not parse while none was followed: the verdict says why."""
        self.ack = StreamAck(
            id=None if sample is None else sample.id,
            session=None if sample is None else sample.session,
            state="rejected", reason=reason, t=time.time(),
        )  # fmt: skip

    def _set(self, state: str, reason: str | None, braked: bool) -> None:
        a = self.active
        assert a is not None
        self.ack = StreamAck(
            id=a.id, session=a.session, state=state, reason=reason, braked=braked,  # type: ignore[arg-type]
            seq=a.latest.seq, n=a.n, t=time.time(),
        )  # fmt: skip

    def status(self) -> StreamAck | None:
        """The verdict for the status; while streaming with the current ``seq`` and ``n``."""
        a = self.active
        if a is not None and self.ack is not None and self.ack.state == "streaming":
            self.ack = self.ack.model_copy(update={"seq": a.latest.seq, "n": a.n})
        return self.ack
