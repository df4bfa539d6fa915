"""``beamrelay calibrate collect handeye|beam``: collect a calibration dataset on the running
system (real or simulated): planned, well-conditioned poses, each move checked with the
safety geometry, markers or spots from the camera; writes the dataset file that
``beamrelay calibrate handeye|beam`` reads. How: :mod:`planner.service.collect`.
"""

from __future__ import annotations

import dataclasses
import json
import signal
import threading
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.calibration.collect import SPEED, SPEED_RANGE
from planner.cli.args import command_group, parse_xyz
from planner.cli.node import EndpointOpt, PrefixOpt, ZenohConfigOpt
from planner.errors import InputError

app = command_group(help="Collect calibration data on the running system (moves the robot).")

ScenarioOpt = Annotated[Path, typer.Option("--scenario", "-s", help="Scenario YAML.")]
OutOpt = Annotated[Path, typer.Option("--output", "-o", help="Dataset JSON to write.")]
RobotOpt = Annotated[str, typer.Option("--robot", help="Robot to move (e.g. arm0).")]
PosesOpt = Annotated[int, typer.Option("--poses", help="Poses to collect.")]
SpeedOpt = Annotated[float, typer.Option("--speed", help="Peak joint speed of the moves, rad/s.")]
SeedOpt = Annotated[int, typer.Option("--seed", help="Pose generator seed.")]


def _setup(scenario: Path, robot: str, poses: int, speed: float, output: Path) -> Any:
    from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
    from planner.safety.geometry import SafetyWorld
    from planner.safety.shapes import volumes_from_scene_items

    if not scenario.is_file():
        raise InputError("scenario not found", str(scenario))
    if not 3 <= poses <= 200:
        raise InputError(f"must be in [3, 200], got {poses}", "--poses")
    if not SPEED_RANGE[0] <= speed <= SPEED_RANGE[1]:
        raise InputError(f"must be in [{SPEED_RANGE[0]:g}, {SPEED_RANGE[1]:g}] rad/s, got {speed:g}",
                         "--speed")  # fmt: skip
    if output.suffix != ".json" or not output.parent.is_dir():
        raise InputError("expected a *.json file in an existing directory", f"--output {output}")
    scn = load_scenario(scenario)
    system = system_from_scenario(scn)
    if robot not in system.robot_names:
        raise InputError(f"unknown robot {robot!r}; the scenario has {', '.join(system.robot_names)}",
                         "--robot")  # fmt: skip
    if system.camera is None:
        raise InputError("collection needs system.camera in the scenario", str(scenario))
    scene = volumes_from_scene_items(scene_objects(scn))  # type: ignore[arg-type]
    return system, SafetyWorld(system, scene), scn.model.system.laser


def _static_check(system: Any, world: Any, robot: str) -> Any:
    """A pose test: no collision at ``q`` with the other robots at home."""
    import numpy as np

    from planner.safety.sweep import check_sweep

    def ok(q: Any) -> bool:
        Q = np.concatenate([q if r.name == robot else r.home for r in system.robots])
        return check_sweep(world, np.zeros(1), Q[None]) is None

    return ok


@app.command("handeye")
def handeye(
    scenario: ScenarioOpt,
    output: OutOpt,
    robot: RobotOpt = "arm0",
    poses: PosesOpt = 12,
    speed: SpeedOpt = SPEED,
    board_offset: Annotated[
        str, typer.Option(help="Nominal board origin on the flange X,Y,Z (m), eye_to_hand.")
    ] = "0,0,0.01",
    seed: SeedOpt = 0,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Hand-eye (eye_to_hand): ChArUco board on the flange, camera fixed."""
    import numpy as np

    from drivers.camera.markers import CharucoSpec
    from planner.calibration.collect import handeye_plan
    from planner.calibration.dataset import handeye_json, write_json
    from planner.calibration.handeye import HandEyeData
    from planner.model.transforms import make_T

    system, world, _ = _setup(scenario, robot, poses, speed, output)
    spec = CharucoSpec()
    board = spec.points() - np.array([spec.squares_x, spec.squares_y, 0]) * spec.square / 2
    board_pose = make_T(p=parse_xyz(board_offset, "--board-offset"))
    rng = np.random.default_rng(seed)
    qs, cond = handeye_plan(system, robot, "eye_to_hand", poses, board, board_pose, rng,
                            feasible=_static_check(system, world, robot))  # fmt: skip
    typer.echo(f"{len(qs)} poses planned; condition number of the hand-eye Jacobian {cond:.1f}")
    request = {"robot": robot, "board_points": board.tolist(), "board_pose": board_pose.tolist(),
               "charuco": dataclasses.asdict(spec)}  # fmt: skip
    got_q, got_p, log = _run(system, world, robot, qs, speed, endpoint, prefix, zenoh_config,
                             lambda bp: bp.markers(request))  # fmt: skip
    data = HandEyeData(robot, "eye_to_hand", board, np.array(got_q), np.array(got_p))
    _finish(output, handeye_json(data) if got_q else None, log, len(qs), write_json)


@app.command("beam")
def beam(
    scenario: ScenarioOpt,
    output: OutOpt,
    aim: Annotated[str, typer.Option("--aim", help="Board centre X,Y,Z in the world (m).")],
    robot: RobotOpt = "arm0",
    poses: PosesOpt = 16,
    speed: SpeedOpt = SPEED,
    board: Annotated[int, typer.Option("--board", help="Placement label of this board.")] = 0,
    seed: SeedOpt = 0,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Beam: laser spots on a board placed at --aim, one placement per run."""
    import numpy as np

    from planner.calibration.collect import beam_plan
    from planner.calibration.dataset import write_json

    system, world, laser = _setup(scenario, robot, poses, speed, output)
    if laser.gate is not None and laser.aim is None:
        raise InputError("beam collection reads spots under the aiming beam, never the "
                         "treatment gate: set laser.aim (aim: gate for a diagnostic-diode-only "
                         "rig)", "laser.aim")  # fmt: skip
    if system.robot_names.index(robot) != 0:
        raise InputError("collects for the first robot of the chain only (for now)", "--robot")
    rng = np.random.default_rng(seed)
    qs, cond = beam_plan(system, robot, poses, np.asarray(parse_xyz(aim, "--aim")), rng,
                         feasible=_static_check(system, world, robot))  # fmt: skip
    typer.echo(f"{len(qs)} poses planned; condition number of the beam Jacobian {cond:.1f}")
    gate = laser.gate

    def observe(bp: Any) -> Any:  # the spot, under the aiming beam when the laser is gated
        return bp.spot() if gate is None else bp.aimed_spot(gate.robot)

    got_q, got_p, log = _run(system, world, robot, qs, speed, endpoint, prefix, zenoh_config,
                             observe)  # fmt: skip
    doc = {"schema": "beamrelay.beam/1", "robot": robot,
           "samples": [{"q": {robot: q.tolist()}, "spot_camera": p.tolist(), "board": board}
                       for q, p in zip(got_q, got_p, strict=True)]}  # fmt: skip
    _finish(output, doc if got_q else None, log, len(qs), write_json)


def _run(system: Any, world: Any, robot: str, qs: Any, speed: float, endpoint: str | None,
         prefix: str, zenoh_config: Path | None, observe: Any) -> tuple[list[Any], list[Any], list[str]]:  # fmt: skip
    """Visit every pose, then return to the start; (joints reached, observations, log lines)."""
    from planner.bus.session import Keys, open_session
    from planner.service.collect import BusPlanner
    from planner.service.heartbeat import BusAddress

    _interrupt_on_sigterm()
    session = open_session(listen=False, endpoint=endpoint, config_file=zenoh_config)
    try:
        bp = BusPlanner(session, Keys(prefix), system, bus=BusAddress(endpoint, zenoh_config))
    except BaseException:  # its subscribers' threads would keep the process alive
        session.close()
        raise
    try:
        return _visit(bp, system, robot, qs, speed, world, observe)
    except KeyboardInterrupt:  # SIGTERM (the console's Cancel, up stopping) or Ctrl-C
        typer.echo("interrupted: the arm brakes where it is (not returned to the start pose)")
        raise
    finally:
        bp.close()
        session.close()


def _visit(bp: Any, system: Any, robot: str, qs: Any, speed: float, world: Any,
           observe: Any) -> tuple[list[Any], list[Any], list[str]]:  # fmt: skip
    """The poses visited through ``bp`` (a :class:`~planner.service.collect.BusPlanner`),
    then the return; (joints reached, observations, log lines). A move the driver braked on
    late heartbeats is made once more from where the arm stopped, once it rests (any other
    reason is not); after an operator's STOP no further pose is visited and the arm stays
    where it braked."""
    import numpy as np

    from schemas.brakes import Brake

    got_q: list[Any] = []
    got_p: list[Any] = []
    log: list[str] = []
    # the poses the arm went through, joined by moves that were checked clear; lost once
    # a move ended early (the arm may have stopped anywhere)
    trail = [bp.wait_joints()[robot].copy()]
    lost = False
    home = system.robot(robot).home
    for i, q in enumerate(qs):
        why = bp.move(robot, q, speed, world)
        if why is not None and why.late_heartbeat and bp.wait_rest(robot):
            typer.echo(f"pose {i + 1}/{len(qs)}: {why}; once more from where the arm rests")
            why = bp.move(robot, q, speed, world)
        if why is not None and why.collided:
            back = bp.move(robot, home, speed, world)  # the direct path collides
            if back is None:  # go through home
                trail.append(np.array(home, dtype=float))
                why = bp.move(robot, q, speed, world)
            elif not back.collided:
                why = back
        if why is None:
            trail.append(np.array(q, dtype=float))
        elif not why.collided:
            lost = True
        obs = observe(bp) if why is None else None
        if why is None and (obs is None or not np.any(np.isfinite(obs))):
            why = "nothing seen by the camera"
        line = f"pose {i + 1}/{len(qs)}: " + ("ok" if why is None else f"skipped ({why})")
        typer.echo(line)
        log.append(line)
        if why is None:
            got_q.append(bp.wait_joints()[robot].copy())
            got_p.append(obs)
        elif why.brake is Brake.OPERATOR_STOP:
            typer.echo("stopped by the operator: no further pose")
            break
    typer.echo(_return(bp, robot, None if lost else trail, speed, world))
    return got_q, got_p, log


def _interrupt_on_sigterm() -> None:
    """SIGTERM (the console's Cancel, or ``up`` stopping) ends the run as Ctrl-C does: the
    heartbeat stops at once (the driver brakes an arm still moving within its 0.1 s
    timeout), the session closes, no dataset is written, exit status 130."""

    def on_term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_term)


def _return(bp: Any, robot: str, trail: list[Any] | None, speed: float, world: Any) -> str:
    """Move the arm back to where the collection found it (``trail[0]``), so the next
    collection or plan starts from there: directly when that move is clear, else one step
    back along ``trail`` (poses joined by moves that were checked clear and made on the way
    out) and try again. Every move is checked again before it is sent. The line to print."""
    if trail is None:
        return "not returned to the start pose: a move ended early (the arm rests where it stopped)"
    moves = 0
    while len(trail) > 1:
        why = bp.move(robot, trail[0], speed, world)
        if why is None:
            return f"returned to the start pose ({moves + 1} moves)"
        if not why.collided:
            return f"not returned to the start pose: {why}"
        trail.pop()
        why = bp.move(robot, trail[-1], speed, world)  # back along a move made on the way out
        if why is not None:
            return f"not returned to the start pose: {why}"
        moves += 1
    return "the arm is at its start pose"


def _finish(output: Path, doc: dict[str, Any] | None, log: list[str], n: int, write: Any) -> None:
    ok = sum(line.endswith("ok") for line in log)
    if doc is not None:
        write(output, doc)
    typer.echo(json.dumps({"output": str(output) if doc else None, "planned": n, "collected": ok}))
    if ok < min(n, 3):
        raise typer.Exit(1)
