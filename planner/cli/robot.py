"""``beamrelay robot recover``: the operator's acknowledgement after a robot fault.

After a protective stop, an emergency stop, a safeguard stop, a lost RTDE link or a tripped
RTDE watchdog, a UR driver refuses to move until an operator, who has checked the cell,
says so: this command publishes ``{"schema": "beamrelay.recover/1", "robot", "t",
"operator"}`` on ``<prefix>/<robot>/recover``. The driver then checks that the cause is
gone, re-uploads its control script, re-arms the RTDE watchdog and re-synchronises to the
measured joints; ``beamrelay up`` restarts a hardware driver that died. The command waits
for the robot's status and exits 0 when the robot is out of fault, 1 when the driver refused
(with its reason) or did not answer.
"""

from __future__ import annotations

import getpass
import threading
import time
from typing import Annotated, Any

import typer

from planner.cli.args import command_group
from planner.cli.node import EndpointOpt, PrefixOpt, ZenohConfigOpt
from planner.errors import InputError

app = command_group(help="Operator actions on a robot driver (recover after a fault).")


@app.command("recover")
def recover(
    name: Annotated[str, typer.Option("--name", help="Robot name (e.g. arm0).")],
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the driver.")] = 20.0,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Acknowledge a robot fault: the driver re-arms (script, RTDE watchdog) if the cause is gone."""
    from drivers.robot.ur_link import recover_body, recover_key
    from planner.bus.session import Keys, decode, open_session
    from schemas.messages import RobotStatus

    if not name or "/" in name or "*" in name or any(c.isspace() for c in name):
        raise InputError(f"not a robot name: {name!r}", "--name")
    if not 0 < timeout <= 600:
        raise InputError(f"must be in (0, 600] s, got {timeout:g}", "--timeout")
    keys = Keys(prefix)
    session = open_session(listen=False, endpoint=endpoint, config_file=zenoh_config)
    statuses: list[tuple[float, RobotStatus]] = []
    got = threading.Event()

    def on_status(sample: Any) -> None:
        try:
            statuses.append((time.monotonic(), decode(sample.payload.to_bytes(), RobotStatus)))
        except InputError:
            return
        got.set()

    sub = session.declare_subscriber(keys.status(name), on_status)
    try:
        got.wait(min(1.0, timeout))
        sent = time.monotonic()
        session.put(recover_key(prefix, name), recover_body(name, getpass.getuser()))
        verdict = _wait_verdict(statuses, sent, sent + timeout)
    finally:
        sub.undeclare()
        session.close()
    if verdict is None:
        typer.echo(f"{name}: no status from the driver within {timeout:g} s", err=True)
        raise typer.Exit(1)
    ok, text = verdict
    typer.echo(f"{name}: {text}", err=not ok)
    if not ok:
        raise typer.Exit(1)


def _wait_verdict(
    statuses: list[tuple[float, Any]], sent: float, deadline: float
) -> tuple[bool, str] | None:
    """(recovered, text) from the first telling status after the request, or None."""
    settle = sent + 0.3  # statuses published before the driver saw the request
    while time.monotonic() < deadline:
        for t, st in list(statuses):
            if t < settle:
                continue
            fault = st.fault or ""
            if "recover refused" in fault or "recover failed" in fault:
                return False, fault
            if st.mode != "fault":
                return True, f"{st.mode}{f' ({fault})' if fault else ''}"
        time.sleep(0.05)
    return None
