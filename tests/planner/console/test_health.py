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
