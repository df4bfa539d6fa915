"""Setpoint checks and the callback-side intake: every bad body gets a reason naming the
field with its figures; streams are told apart, continued, ended and ignored as documented."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from drivers.robot.setpoint_check import (
    MAX_SETPOINT_BYTES,
    SetpointSample,
    check_next,
    check_stream_start,
    parse_setpoint,
)
from drivers.robot.setpoint_intake import SetpointIntake
from planner.errors import InputError
from planner.model.system import DEFAULT_HOME, JOINT_NAMES_UR, Limits
from tests.drivers.robot.fake_bus import SimClock

HOME = np.array(DEFAULT_HOME)
LIMITS = Limits.ur_default()
NAMES = JOINT_NAMES_UR


def body(**kw: Any) -> bytes:
    msg = {"schema": "beamrelay.setpoint/1", "robot": "arm0", "t": 100.0, "session": "S",
           "seq": 0, "id": "r", "q": HOME.tolist(), "qd": [0.0] * 6, "laser_on": False}  # fmt: skip
    msg.update(kw)
    return json.dumps(msg).encode()


def parse(data: bytes) -> SetpointSample:
    return parse_setpoint(data, 0.0, "arm0", NAMES, LIMITS)


def reason(data: bytes) -> str:
    with pytest.raises(InputError) as e:
        parse(data)
    return str(e.value)


def test_a_good_setpoint_parses() -> None:
    s = parse(body(seq=7, laser_on=True, qd=[0.1] * 6))
    assert (s.session, s.id, s.seq, s.t, s.laser_on) == ("S", "r", 7, 100.0, True)
    np.testing.assert_array_equal(s.q, HOME)
    np.testing.assert_array_equal(s.qd, np.full(6, 0.1))
    assert parse(body(id=None)).key == ("S", None)


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (body(q=[0.0] * 5, qd=[0.0] * 5), "q: expected 6 numbers (one per joint), got 5"),
        (body(q=[0.0] * 5), "qd: expected 5 numbers (as q), got 6"),
        (body(qd=[0.0] * 5), "qd: expected 6 numbers (as q), got 5"),
        (body(q=[], qd=[]), "q: "),
        (body(robot="arm1"), "robot: setpoint is for robot 'arm1', this driver is 'arm0'"),
        (body().replace(b'"qd": [0.0', b'"qd": [NaN'), "qd[0]: expected a finite number, got nan"),
        (body().replace(b'"t": 100.0', b'"t": Infinity'), "t: expected a finite number, got inf"),
        (
            body(q=[*HOME[:2], 3.5, *HOME[3:]]),
            "q: 3.5000 rad on joint elbow above upper limit 3.1416 rad",
        ),
        (
            body(q=[-7.0, *HOME[1:]]),
            "q: -7.0000 rad on joint shoulder_pan below lower limit -6.2832 rad",
        ),
        (body(qd=[0, 0, 0, 0, 0, -3.2]), "qd: -3.2000 rad/s on joint wrist_3 exceeds 3.1416 rad/s"),
        (body(seq=-1), "seq: must be >= 0, got -1"),
        (body(session=""), "session: "),
        (body(extra=1), "extra: unknown key"),
        (b"\xff\xfe", "body: invalid JSON: body is not UTF-8 text (byte 0 is 0xff)"),
        (b"[1, 2]", "body: expected a mapping, got a list of 2"),
        (b"null", "body: "),
        (body().replace(b'"S"', b'"\\ud800"'), "session: text holds a lone UTF-16 surrogate"),
        (body().replace(b'"seq": 0', b'"seq": 1' + b"0" * 5000), "seq: expected an integer"),
        (b"[" * 100_00 + b"]" * 100_00, "body: "),
        (b" " * (MAX_SETPOINT_BYTES + 1), f"body: payload of {MAX_SETPOINT_BYTES + 1} bytes"),
    ],
)
def test_bad_bodies_are_refused_with_the_field(data: bytes, expected: str) -> None:
    assert reason(data).startswith(expected)


def sample(t: float, q: np.ndarray, qd: np.ndarray | None = None, seq: int = 0,
           received: float = 0.0, id: str = "r") -> SetpointSample:  # fmt: skip
    qd = np.zeros(6) if qd is None else qd
    return SetpointSample(received, t, "S", seq, id, q, qd, False)


def test_consecutive_positions_against_the_velocity_limit() -> None:
    a = sample(1.0, HOME, seq=1)
    step = 0.99 * math.pi * 0.002  # just inside the limit over 2 ms
    ok = check_next(a, sample(1.002, HOME + step, seq=2), NAMES, LIMITS)
    assert ok.qdd is not None and np.all(ok.qdd == 0)
    with pytest.raises(InputError) as e:
        check_next(a, sample(1.002, HOME + np.eye(6)[5] * 0.05, seq=2), NAMES, LIMITS)
    # 0.05 rad / 0.002 s = 25 rad/s
    assert str(e.value) == (
        "q: wrist_3 moves 0.0500 rad in 0.0020 s since seq 1 = 25.0 rad/s > 3.1416 rad/s"
    )


def test_consecutive_velocities_against_the_acceleration_limit() -> None:
    a = sample(1.0, HOME, np.zeros(6), seq=1)
    qd = np.eye(6)[1] * 0.009  # 4.5 rad/s^2 over 2 ms: inside
    ok = check_next(a, sample(1.002, HOME, qd, seq=2), NAMES, LIMITS)
    assert ok.qdd is not None
    np.testing.assert_allclose(ok.qdd, qd / 0.002)
    with pytest.raises(InputError) as e:
        check_next(a, sample(1.002, HOME, qd * 2, seq=2), NAMES, LIMITS)
    assert str(e.value) == ("qd: shoulder_lift velocity changes 0.0180 rad/s in 0.0020 s since "
                            "seq 1 = 9.0 rad/s^2 > 5.0000 rad/s^2")  # fmt: skip


def test_time_and_seq_must_increase() -> None:
    a = sample(1.0, HOME, seq=5)
    with pytest.raises(InputError, match=r"^seq: 5 does not follow 5"):
        check_next(a, sample(1.002, HOME, seq=5), NAMES, LIMITS)
    with pytest.raises(InputError, match=r"^t: 1.000000 s is not after the previous"):
        check_next(a, sample(1.0, HOME, seq=6), NAMES, LIMITS)


def test_stream_start_near_the_current_state() -> None:
    check_stream_start(sample(0, HOME + 0.009, np.full(6, 0.09)), HOME, np.zeros(6), NAMES)
    with pytest.raises(InputError) as e:
        check_stream_start(sample(0, HOME + np.eye(6)[2] * 0.05), HOME, np.zeros(6), NAMES)
    assert str(e.value) == ("q: stream starts 0.0500 rad from the current state on joint elbow "
                            "(tolerance 0.01 rad)")  # fmt: skip
    with pytest.raises(InputError) as e:
        check_stream_start(sample(0, HOME, np.eye(6)[0] * 0.5), HOME, np.zeros(6), NAMES)
    assert str(e.value) == ("qd: stream starts 0.5000 rad/s from the current state on joint "
                            "shoulder_pan (tolerance 0.1 rad/s)")  # fmt: skip


# -- intake ----------------------------------------------------------------------------------


def intake() -> tuple[SetpointIntake, SimClock]:
    clock = SimClock()
    return SetpointIntake("arm0", NAMES, LIMITS, clock=clock), clock


def kinds(events: list[Any]) -> list[tuple[str, int]]:
    return [(e.kind, e.stream) for e in events]


def test_streams_start_continue_and_coalesce() -> None:
    it, clock = intake()
    for k in range(5):
        it.submit(body(seq=k, t=100 + 0.002 * k))
        clock.t += 0.002
    ev = it.take()
    assert kinds(ev) == [("start", 1), ("next", 1)]  # four "next" coalesced into the newest
    assert ev[1].sample is not None and ev[1].sample.seq == 4
    assert it.take() == []


def test_a_rejected_setpoint_ends_the_stream_and_its_followers_are_ignored() -> None:
    it, clock = intake()
    it.submit(body(seq=0, t=100.0))
    clock.t += 0.002
    it.submit(body(seq=1, t=100.002, q=(HOME + 0.05).tolist()))  # 25 rad/s
    for k in range(2, 30):  # the sender goes on for 56 ms without a pause
        clock.t += 0.002
        it.submit(body(seq=k, t=100 + 0.002 * k))
    ev = it.take()
    assert kinds(ev) == [("start", 1), ("rejected", 1)]
    assert ev[1].reason is not None and ev[1].reason.startswith("q: shoulder_pan moves 0.0500")
    assert it.n_ignored == 28
    clock.t += 0.051  # a pause of more than 50 ms: the next setpoint starts a new stream
    it.submit(body(seq=40, t=101.0))
    assert kinds(it.take()) == [("start", 2)]


def test_a_new_id_starts_at_once_but_two_streams_at_once_end_both() -> None:
    it, clock = intake()
    it.submit(body(seq=0, id="a"))
    it.end(1)  # the loop ended it (say a stop): "a" is ignored now, "b" may start
    clock.t += 0.002
    it.submit(body(seq=1, id="a", t=100.002))
    it.submit(body(seq=0, id="b", t=100.002))
    clock.t += 0.002
    it.submit(body(seq=0, id="c", t=100.004))  # while "b" is followed
    ev = it.take()
    assert kinds(ev) == [("start", 1), ("start", 2), ("rejected", 2)]
    assert ev[2].reason == ("session: setpoint of stream session S id c while stream session S "
                            "id b is followed")  # fmt: skip
    clock.t += 0.002
    it.submit(body(seq=1, id="b", t=100.006))
    it.submit(body(seq=1, id="c", t=100.006))
    assert it.take() == [] and it.n_ignored == 3


def test_garbage_ends_the_open_stream_and_is_reported_otherwise() -> None:
    it, clock = intake()
    it.submit(b"garbage")
    it.submit(body(seq=0))
    clock.t += 0.002
    it.submit(b'{"schema": "beamrelay.setpoint/1"}')
    ev = it.take()
    assert kinds(ev) == [("rejected", 0), ("start", 1), ("rejected", 1)]
    assert ev[0].reason is not None and ev[0].reason.startswith("body: invalid JSON")
    assert ev[2].reason == "robot: missing required key"


def test_a_silent_stream_ends_by_itself() -> None:
    it, clock = intake()
    it.submit(body(seq=0))
    clock.t += 0.0505
    it.submit(body(seq=1, t=100.002))  # continues the values, but after 50.5 ms of silence
    assert kinds(it.take()) == [("start", 1), ("start", 2)]


def test_events_stay_bounded_under_a_flood() -> None:
    it, _ = intake()
    for k in range(1000):
        it.submit(b"x" if k % 2 else body(seq=k, id=str(k)))
    ev = it.take()
    assert len(ev) <= 2 * 64 and it.n_dropped > 0
    assert it.n_received == 1000
