"""``beamrelay record`` / ``beamrelay replay``: the bus to an MCAP file and back.

A lab sends a session to a colleague; a bug is reproduced without the cell. Format and
safety rules: :mod:`drivers.record`.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from drivers.record import CLOUD_RATE
from planner.cli.args import stop_on_signals
from planner.cli.node import EndpointOpt, PrefixOpt, ZenohConfigOpt
from planner.errors import InputError


# long: a typer command: 9 options declared in its signature (31 lines); its code is 48 lines
def record(
    output: Annotated[Path, typer.Option("--output", "-o", help="MCAP file to write.")],
    duration: Annotated[
        float | None, typer.Option(help="Stop after this many seconds (default: Ctrl-C).")
    ] = None,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    zenoh_config: ZenohConfigOpt = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing file.")] = False,
    cloud_rate: Annotated[
        float,
        typer.Option(
            "--cloud-rate",
            help="Point clouds kept per second (the camera sends 15; 0 keeps every one).",
        ),
    ] = CLOUD_RATE,
    ros2: Annotated[
        bool,
        typer.Option(
            "--ros2", help="Also write ROS 2 channels (JointState; TF, markers with --scenario)."
        ),
    ] = False,
    scenario: Annotated[
        Path | None,
        typer.Option(
            "--scenario",
            help="Scenario of the running system (TF tree for --ros2).",
            dir_okay=False,
        ),
    ] = None,
) -> None:
    """Record every bus key under the prefix (and liveliness) with timestamps to MCAP
    (zstd-compressed; point clouds decimated to --cloud-rate).

    With --ros2 the file also holds ROS 2 channels (ros2msg schemas, CDR) that Foxglove and
    ros2 bag read: /<robot>/joint_states and, with --scenario, /tf, /tf_static and
    /beamrelay/markers (the beam, the targets)."""
    from drivers.record import Recorder
    from planner.bus.session import Keys, open_session

    if duration is not None and not 0 < duration <= 86400:
        raise InputError(f"must be in (0, 86400] s, got {duration:g}", "--duration")
    if not 0 <= cloud_rate <= 1000:
        raise InputError(f"must be in [0, 1000] Hz, got {cloud_rate:g}", "--cloud-rate")
    if output.suffix != ".mcap":
        raise InputError("the recording is MCAP: name it *.mcap", f"--output {output}")
    if output.exists() and not force:
        raise InputError("exists (use --force to overwrite)", f"--output {output}")
    if not output.parent.is_dir():
        raise InputError("no such directory", f"--output {output}")
    if scenario is not None and not ros2:
        raise InputError("--scenario gives the TF tree of the ROS 2 channels: add --ros2")
    translator = None
    if ros2:
        from planner.ros2.recording import RosTranslator

        translator = RosTranslator(Keys(prefix))
        if scenario is not None:
            from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
            from planner.model.scene import SceneModel

            if not scenario.is_file():
                raise InputError(f"scenario not found: {scenario}")
            scn = load_scenario(scenario)
            scene = SceneModel(scene_objects(scn))
            translator = RosTranslator(Keys(prefix), system_from_scenario(scn), scene)
    stop = stop_on_signals()
    session = open_session(listen=False, endpoint=endpoint, config_file=zenoh_config)
    tmp = output.with_suffix(".mcap.part")
    t0 = time.monotonic()
    try:
        with tmp.open("wb") as f:
            rec = Recorder(session, prefix, f, cloud_rate, ros=translator)
            typer.echo(f"recording {prefix}/** to {output} (Ctrl-C to stop)", err=True)
            stop.wait(duration)
            n = rec.close()
        tmp.replace(output)  # a complete file only, never a truncated one under the name
    finally:
        session.close()
        tmp.unlink(missing_ok=True)
    dropped = (
        f", {rec.clouds_dropped} point clouds skipped (--cloud-rate)" if rec.clouds_dropped else ""
    )
    size = output.stat().st_size / 1e6
    typer.echo(f"{output}: {n} messages in {time.monotonic() - t0:.1f} s, {size:.1f} MB{dropped}")


def replay(
    recording: Annotated[Path, typer.Argument(help="MCAP file written by beamrelay record.")],
    speed: Annotated[
        float, typer.Option(help="Playback speed: 1 = original timing, 0 = as fast as possible.")
    ] = 1.0,
    commands: Annotated[
        bool,
        typer.Option(
            "--commands",
            help="Also replay trajectories, setpoints, heartbeats, stop, recover, targets "
            "(refused while a robot driver is alive on the bus).",
        ),
    ] = False,
    endpoint: EndpointOpt = None,
    listen: Annotated[
        bool, typer.Option("--listen", help="Host the bus (when nothing else does).")
    ] = False,
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Play a recording back onto the bus (original bytes, keys and timing)."""
    from drivers.record import read
    from drivers.record import replay as play
    from planner.bus.session import open_session

    if not recording.is_file():
        raise InputError("recording not found", str(recording))
    if not (0 <= speed <= 1000):
        raise InputError(f"must be in [0, 1000], got {speed:g}", "--speed")
    next(iter(read(recording)), None)  # a bad file is a user error before touching the bus
    stop = stop_on_signals()
    session = open_session(listen=listen, endpoint=endpoint, config_file=zenoh_config)
    try:
        time.sleep(0.5)  # let subscribers connect before the first message
        sent, skipped = play(session, recording, speed=speed, commands=commands, stop=stop)
    finally:
        session.close()
    note = f", {skipped} command messages skipped (--commands to include)" if skipped else ""
    typer.echo(f"{recording}: {sent} messages replayed{note}")
