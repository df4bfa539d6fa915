"""The health panel text from a bus snapshot."""

from __future__ import annotations

from planner.console.health import health_markdown
from planner.console.live import Stamped
from schemas.messages import Heartbeat, LaserState, RobotStatus, SpotMessage


def snap(**kw: object) -> dict[str, object]:
    base: dict[str, object] = {"alive": [], "spot": None, "status": {}, "laser": None,
                               "heartbeat": None, "rejected": 0}  # fmt: skip
    return base | kw


def test_everything_down_and_silent() -> None:
    text = health_markdown(snap(), {"arm0": 0.0}, ("planner", "camera", "arm0"), now=100.0)
    assert "`planner`: **DOWN**" in text and "`arm0`: **DOWN**, 0 Hz" in text
    assert "heartbeat: **silent**" in text and "spot: no camera frames" in text
    assert "laser gate: no report" in text


def test_a_running_system_with_a_fault_and_the_laser_on() -> None:
    now = 50.0
    st = RobotStatus(robot="arm0", t=1.0, mode="running", protective_stop=True, fault="joint 3")
    s = snap(
        alive=["planner", "camera", "arm0"],
        status={"arm0": Stamped(st, now)},
        heartbeat=Stamped(Heartbeat(t=1.0, session="s1", seq=3), now - 0.05),
        laser=Stamped(LaserState(robot="arm0", t=1.0, on=True), now),
        spot=Stamped(SpotMessage(t=1.0, p_camera=[0.0, 0.0, 1.0], confidence=0.8), now - 0.1),
        rejected=2,
    )
    text = health_markdown(s, {"arm0": 250.0, "heartbeat": 100.0}, ("planner", "arm0"), now)
    assert "`arm0`: up, 250 Hz, running, **protective stop**, **fault: joint 3**" in text
    assert "heartbeat: ok, 100 Hz" in text
    assert "laser gate: **ON** (arm0)" in text
    assert "spot: seen, confidence 0.80" in text
    assert "2 malformed messages dropped" in text
    late = s | {"heartbeat": Stamped(Heartbeat(t=1.0, session="s1", seq=3), now - 0.2)}
    assert "heartbeat: **silent**" in health_markdown(late, {}, ("planner",), now)


def test_no_line_says_off_for_a_laser_without_a_gate() -> None:
    text = health_markdown(snap(), {}, ("planner",), now=100.0, gated=False)
    assert "laser: **no gate** in this scenario" in text and "always on" in text
    assert "off" not in text.split("laser:")[1].split("  \n")[0]
    assert "laser gate" not in text


def test_a_burst_of_queued_heartbeats_does_not_read_as_a_rate() -> None:
    """100 Hz heartbeats, then 280 ms with none and the 28 queued ones arriving within 23 ms
    (what once read 1275 Hz): the rate over the last second still reads 100 Hz; a stream
    younger than the window is measured over its age; a silent one reads 0."""
    from planner.bus.session import Keys
    from planner.console.live import RATE_WINDOW, STALE_AFTER, LiveState
    from tests.fake_clock import FakeClock

    clock = FakeClock()
    live = LiveState(Keys("healthtest"), clock=clock)
    for _ in range(50):  # 0.5 s at 100 Hz
        live._tick("heartbeat")
        clock.advance(0.01)
    assert abs(live.rate("heartbeat") - 100.0) < 1e-6  # younger than the window: its age
    for _ in range(100):  # 1 s more at 100 Hz
        live._tick("heartbeat")
        clock.advance(0.01)
    clock.advance(0.27)  # silent 280 ms ...
    for _ in range(28):  # ... then its 28 queued beats within 23 ms
        live._tick("heartbeat")
        clock.advance(0.023 / 28)
    window = [t for t in live._arrivals["heartbeat"] if t > clock.t - RATE_WINDOW]
    assert live.rate("heartbeat") == len(window) / RATE_WINDOW
    assert 95.0 <= live.rate("heartbeat") <= 105.0  # 1 s holds ~100 beats, not 1275 Hz
    clock.advance(STALE_AFTER + 0.01)
    assert live.rate("heartbeat") == 0.0
    assert live.rate("spot") == 0.0  # never seen


def test_the_last_fault_and_the_keep_out_count_stay_on_the_panel() -> None:
    """A fault a driver reported stays as the last fault, with its age, after the driver
    cleared it; a repeated report keeps its first time; the keep-out count is shown."""
    from types import SimpleNamespace

    from planner.bus.session import Keys
    from planner.console.live import LiveState
    from tests.fake_clock import FakeClock

    clock = FakeClock()
    live = LiveState(Keys("healthtest"), clock=clock)

    def report(**kw: object) -> None:
        st = RobotStatus(robot="arm0", t=1.0, mode="stopped", **kw)  # type: ignore[arg-type]
        body = SimpleNamespace(to_bytes=lambda: st.model_dump_json().encode())
        live._on_status(SimpleNamespace(key_expr="healthtest/arm0/status", payload=body))

    text = health_markdown(live.snapshot(), {}, ("arm0",), clock.t, keep_out=0)
    assert "last fault: none since the console started" in text
    assert "keep-out volumes: **none**" in text
    report(fault="planner heartbeat lost")
    clock.advance(3.0)
    report(fault="planner heartbeat lost")  # the same fault again: its first time stays
    clock.advance(9.0)
    report()  # cleared
    text = health_markdown(live.snapshot(), {}, ("arm0",), clock.t, keep_out=2)
    assert "last fault: arm0: planner heartbeat lost (12 s ago)" in text, text
    assert "keep-out volumes: 2" in text
    assert "**fault" not in text  # the driver's status no longer reports it
    report(protective_stop=True)
    assert "last fault: arm0: protective stop (0 s ago)" in health_markdown(
        live.snapshot(), {}, ("arm0",), clock.t
    )


def test_a_stop_for_a_lost_heartbeat_reads_as_past_once_the_heartbeat_is_back() -> None:
    """'heartbeat: ok' beside 'fault: planner heartbeat lost' once read as a contradiction:
    the robot line says the heartbeat is back and the stop still stands."""
    now = 10.0
    st = RobotStatus(robot="arm0", t=1.0, mode="stopped", fault="planner heartbeat lost: s1")
    beat = Stamped(Heartbeat(t=1.0, session="s1", seq=3), now - 0.01)
    s = snap(alive=["arm0"], status={"arm0": Stamped(st, now)}, heartbeat=beat)
    text = health_markdown(s, {"heartbeat": 100.0}, ("arm0",), now)
    assert "heartbeat: ok" in text
    assert ("**fault: planner heartbeat lost: s1** (the heartbeat is back; the robot stays "
            "stopped until a new motion)") in text  # fmt: skip
    silent = health_markdown(s | {"heartbeat": None}, {}, ("arm0",), now)
    assert "heartbeat: **silent**" in silent and "is back" not in silent
