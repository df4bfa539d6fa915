"""``schemas.brakes``: a driver's reason read back as its cause."""

from __future__ import annotations

import pytest

from schemas.brakes import Brake, brake_of


@pytest.mark.parametrize("cause", list(Brake))
def test_every_cause_reads_back_from_what_the_driver_says(cause: Brake) -> None:
    assert brake_of(cause.say(": session p-1 silent for 130 ms")) is cause
    assert brake_of(cause.say(" beamrelay/stop")) is cause
    assert brake_of(cause.value) is cause


def test_a_cause_whose_words_begin_another_is_not_taken_for_it() -> None:
    # "stop requested on" is not the start of "received before the stop requested on", but
    # a shorter value that begins a longer one must lose to it
    assert brake_of("received before the stop requested on beamrelay/stop") is (
        Brake.SENT_BEFORE_STOP
    )
    assert brake_of("stop requested on beamrelay/stop") is Brake.OPERATOR_STOP


@pytest.mark.parametrize(
    "reason",
    [None, "", "protective stop", "q[3]: joint wrist_1 moves 0.5 rad in 2 ms",
     "the planner heartbeat lost", "no planner alive"],
)  # fmt: skip
def test_other_reasons_have_no_cause(reason: str | None) -> None:
    assert brake_of(reason) is None


def test_late_heartbeats_are_the_three_heartbeat_causes() -> None:
    late = {b for b in Brake if b.late_heartbeat}
    assert late == {Brake.HEARTBEAT_LOST, Brake.NO_PLANNER, Brake.SESSION_SILENT}
