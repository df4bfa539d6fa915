"""The node-health panel text: liveliness, heartbeat, driver status and faults, the laser.

A pure function of :meth:`planner.console.live.LiveState.snapshot` and the stream rates, so
it is tested without a bus.
"""

from __future__ import annotations

from typing import Any

from planner.console.live import STALE_AFTER

#: the planner's heartbeat is stale after this silence (s), as the drivers judge it
HEARTBEAT_STALE = 0.1


def health_markdown(snap: dict[str, Any], rates: dict[str, float], nodes: tuple[str, ...],
                    now: float, gated: bool = True, keep_out: int = 0) -> str:  # fmt: skip
    """Markdown lines: one per expected node (alive or DOWN, its stream rate, the robot
    driver's mode and fault), the heartbeat, the laser gate, the spot, the keep-out volumes
    in force (``keep_out``) and the last fault any driver reported, with its age. ``gated``:
    the scenario names a laser gate (without one nothing switches the laser: no line may say
    it is off)."""
    lines = []
    hb = snap["heartbeat"]
    beating = hb is not None and now - hb.at <= HEARTBEAT_STALE
    for node in nodes:
        alive = "up" if node in snap["alive"] else "**DOWN**"
        rate = rates.get(node)
        text = f"`{node}`: {alive}" + (f", {rate:.0f} Hz" if rate is not None else "")
        st = snap["status"].get(node)
        if st is not None:
            m = st.value
            text += f", {m.mode}"
            if m.protective_stop:
                text += ", **protective stop**"
            if m.fault:
                text += f", **fault: {m.fault}**"
                if "heartbeat" in m.fault and beating:  # the stop it caused still stands
                    text += " (the heartbeat is back; the robot stays stopped until a new motion)"
        lines.append(text)
    if not beating:
        lines.append("heartbeat: **silent** (robots brake)")
    else:
        lines.append(f"heartbeat: ok, {rates.get('heartbeat', 0.0):.0f} Hz")
    laser = snap["laser"]
    if not gated:
        lines.append("laser: **no gate** in this scenario (nothing switches it: a simulated "
                     "laser is always on)")  # fmt: skip
    elif laser is None:
        lines.append("laser gate: no report (off until switched)")
    else:
        lines.append(f"laser gate: **{'ON' if laser.value.on else 'off'}** ({laser.value.robot})")
    spot = snap["spot"]
    if spot is None or now - spot.at > STALE_AFTER:
        lines.append("spot: no camera frames")
    elif spot.value.p_camera is None:
        lines.append("spot: not seen")
    else:
        lines.append(f"spot: seen, confidence {spot.value.confidence:.2f}")
    lines.append(f"keep-out volumes: {keep_out}" if keep_out else "keep-out volumes: **none**")
    last = snap.get("last_fault")
    if last is None:
        lines.append("last fault: none since the console started")
    else:
        robot, fault = last.value
        lines.append(f"last fault: {robot}: {fault} ({now - last.at:.0f} s ago)")
    if snap["rejected"]:
        lines.append(f"{snap['rejected']} malformed messages dropped")
    return "  \n".join(lines)
