"""``beamrelay calibrate handeye|beam|simulate|rollback`` (docs/conventions.md: Calibration data).

Heavy imports (CasADi, Pinocchio) happen inside the commands. Bad files and insufficient
or degenerate data end with one line on stderr and exit status 2.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from planner.cli.args import command_group, parse_xyz
from planner.errors import InputError

app = command_group(
    help="Calibrate the camera hand-eye and the laser line + mirror plane; simulate datasets.",
    no_args_is_help=True,
)

ScenarioOpt = Annotated[
    Path, typer.Option("--scenario", "-s", help="Scenario YAML (models, nominal values, gauge).")
]
OutOpt = Annotated[Path, typer.Option("--out", "-o", help="Calibration YAML to write.")]
LossOpt = Annotated[str, typer.Option(help="Robust loss: none, huber or cauchy.")]
ScaleOpt = Annotated[float, typer.Option(help="Robust loss scale, metres.")]


def _check_loss(loss: str, scale: float) -> None:
    from planner.calibration.lsq import LOSSES

    if loss not in LOSSES:
        raise InputError(f"--loss {loss!r}: expected one of {', '.join(LOSSES)}")
    if not scale > 0:
        raise InputError(f"--loss-scale {scale}: must be > 0 (metres)")


def _fail_on_calibration_error(exc: Exception) -> None:
    typer.echo(f"error: {exc}", err=True)
    raise typer.Exit(2)


def _existing_kind(out: Path) -> str | None:
    """``report.kind`` of the calibration file at ``out`` (None: no file, or not one)."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    if not out.is_file():
        return None
    try:
        data = YAML(typ="safe", pure=True).load(out.read_text())
    except (YAMLError, UnicodeDecodeError):
        return None
    report = data.get("report") if isinstance(data, dict) else None
    kind = report.get("kind") if isinstance(report, dict) else None
    return str(kind) if kind is not None else None


def _write(document: dict[str, object], out: Path) -> None:
    """Write the calibration YAML and print its summary. A file holding the other kind of
    calibration (hand-eye vs beam) is never overwritten: both are needed, in two files."""
    from planner.calibration.report import summary_lines, write_calibration

    kind = document["report"]["kind"]  # type: ignore[index]
    held = _existing_kind(out)
    if held is not None and held != kind:
        other = "beam.yaml" if kind == "beam" else "handeye.yaml"
        raise InputError(f"holds the {held} calibration, which the {kind} result would replace: "
                         f"write it to another file (e.g. -o {other}) and include both", str(out))  # fmt: skip
    write_calibration(out, document)
    for line in summary_lines(document):  # type: ignore[arg-type]
        typer.echo(line)
    typer.echo(f"wrote {out}")


def _include_name(out: Path, scenario: Path) -> str:
    """``out`` as the scenario's ``include:`` entry (relative to the scenario's folder)."""
    return os.path.relpath(out.resolve(), scenario.resolve().parent)


def nominal_camera_warning(n_spots: int, scenario: Path, key: str) -> str:
    """The one-line warning for camera-frame spots mapped with an uncalibrated camera."""
    return (
        f"warning: {n_spots} spot_camera spots were mapped to the world with the nominal"
        f" camera pose of {scenario} (no include: gives system.camera.{key}): run `beamrelay"
        f" calibrate handeye` first and add its output to {scenario}'s include: list, or the"
        " mirror and laser come out wrong"
    )


@app.command("handeye")
def handeye(
    data: Annotated[Path, typer.Argument(help="beamrelay.handeye/1 JSON dataset.")],
    scenario: ScenarioOpt,
    out: OutOpt = Path("handeye.yaml"),
    loss: LossOpt = "none",
    loss_scale: ScaleOpt = 0.005,
) -> None:
    """Camera pose and marker-board pose, jointly (eye_to_hand or eye_in_hand)."""
    from planner.calibration.dataset import load_handeye
    from planner.calibration.handeye import calibrate_handeye
    from planner.calibration.report import handeye_document
    from planner.errors import CalibrationError
    from planner.io.scenario import load_scenario, system_from_scenario

    _check_loss(loss, loss_scale)
    system = system_from_scenario(load_scenario(scenario))
    ds = load_handeye(data)
    if ds.robot not in system.robot_names:
        raise InputError(
            f"robot {ds.robot!r} is not in the scenario ({', '.join(system.robot_names)})",
            str(data),
        )
    try:
        result = calibrate_handeye(ds, system, loss=loss, loss_scale=loss_scale)
    except CalibrationError as exc:
        _fail_on_calibration_error(exc)
        return
    document = handeye_document(result, ds.robot, str(data))
    _write(document, out)
    typer.echo(
        f"next: add `include: [{_include_name(out, scenario)}]` to {scenario}, then collect"
        f" beam data and run `beamrelay calibrate beam DATA -s {scenario} -o beam.yaml`"
    )


@app.command("beam")
def beam(
    data: Annotated[Path, typer.Argument(help="beamrelay.beam/1 JSON dataset.")],
    scenario: ScenarioOpt,
    out: OutOpt = Path("beam.yaml"),
    loss: LossOpt = "none",
    loss_scale: ScaleOpt = 0.005,
    mirror_centre: Annotated[
        str | None,
        typer.Option(help="Measured mirror centre X,Y,Z in the flange frame (fiducials) as gauge."),
    ] = None,
    starts: Annotated[int, typer.Option(help="Multi-start count (1 = nominal only).")] = 4,
) -> None:
    """Laser line (if the robot is first) and the robot's mirror plane from 3D spots."""
    import numpy as np

    from planner.calibration.beam import calibrate_beam
    from planner.calibration.dataset import load_beam
    from planner.calibration.report import beam_document
    from planner.errors import CalibrationError
    from planner.io.scenario import load_scenario, system_from_scenario

    _check_loss(loss, loss_scale)
    centre = None if mirror_centre is None else parse_xyz(mirror_centre, "--mirror-centre")
    scn = load_scenario(scenario)
    system = system_from_scenario(scn)
    ds = load_beam(data, system)
    if ds.camera_spots and scn.camera_is_nominal:
        key = (
            "world_T_camera" if system.camera and system.camera.robot is None else "flange_T_camera"
        )
        typer.echo(nominal_camera_warning(ds.camera_spots, scenario, key), err=True)
    try:
        result = calibrate_beam(
            ds,
            system,
            loss=loss,
            loss_scale=loss_scale,
            starts=max(1, starts),
            mirror_centre=None if centre is None else np.array(centre),
        )
    except CalibrationError as exc:
        _fail_on_calibration_error(exc)
        return
    document = beam_document(result, str(data))
    if ds.camera_spots:
        document["report"]["camera_pose"] = {
            "from": scn.camera_pose_file(),
            "nominal": scn.camera_is_nominal,
        }
    _write(document, out)
    names = system.robot_names
    later = names[names.index(ds.robot) + 1 :]
    more = f"; then calibrate {later[0]}'s mirror the same way" if later else ""
    typer.echo(
        f"next: add `include: [{_include_name(out, scenario)}]` to {scenario} (after the"
        f" hand-eye file), then verify with `beamrelay plan {scenario} -o plan.json` and"
        f" `beamrelay check plan.json`{more}"
    )


@app.command("rollback")
def rollback(
    file: Annotated[
        Path, typer.Argument(help="The --online-calibration FILE of serve/up.", dir_okay=False)
    ],
    to: Annotated[
        int | None,
        typer.Option(
            "--to",
            help="Version to go back to (default: the one before the refit"
            " in force; 0 = the calibration before the first refit).",
            min=0,
        ),
    ] = None,
) -> None:
    """Undo an online refit: FILE gets a new version with an earlier version's poses (its
    history is kept in FILE.versions/); a running planner installs it within a second."""
    from planner.service.online import POLL_S
    from planner.service.online_file import history, rollback

    new, back_to, was = rollback(file, to)
    typer.echo(f"{file}: version {new} = version {back_to} (was {was}); a running planner"
               f" with --online-calibration {file} uses it within {POLL_S:g} s, later refits"
               f" start from it")  # fmt: skip
    typer.echo(f"kept versions: {', '.join(str(v) for v in sorted(history(file.resolve())))}")


def _check_simulate_options(
    kind: str, mode: str, spots: str, noise: str, poses: int, boards: int, outliers: float
) -> None:
    """Reject bad ``calibrate simulate`` options (InputError: one line, exit 2)."""
    if kind not in ("handeye", "beam"):
        raise InputError(f"--kind {kind!r}: expected handeye or beam")
    if mode not in ("eye_to_hand", "eye_in_hand"):
        raise InputError(f"--mode {mode!r}: expected eye_to_hand or eye_in_hand")
    if spots not in ("world", "camera"):
        raise InputError(f"--spots {spots!r}: expected world or camera")
    if noise not in ("d435", "none"):
        raise InputError(f"--noise {noise!r}: expected d435 or none")
    if poses < 1 or boards < 1:
        raise InputError("--poses and --boards must be >= 1")
    if not 0.0 <= outliers < 1.0:
        raise InputError(f"--outliers {outliers}: expected a fraction in [0, 1)")


# long: a typer command: 11 options declared in its signature (21 lines); its code is 47 lines
@app.command("simulate")
def simulate(
    scenario: Annotated[
        Path, typer.Argument(help="Scenario YAML; its truth: section is the real geometry.")
    ],
    kind: Annotated[str, typer.Option(help="handeye or beam.")] = "beam",
    mode: Annotated[
        str, typer.Option(help="Hand-eye mode: eye_to_hand or eye_in_hand.")
    ] = "eye_to_hand",
    poses: Annotated[int, typer.Option(help="Poses (per board for beam).")] = 16,
    boards: Annotated[int, typer.Option(help="Board placements (beam).")] = 3,
    noise: Annotated[str, typer.Option(help="d435 or none.")] = "d435",
    outliers: Annotated[float, typer.Option(help="Fraction of points displaced by 1-5 cm.")] = 0.0,
    robot: Annotated[str | None, typer.Option(help="Robot (default: the first).")] = None,
    spots: Annotated[
        str, typer.Option(help="Beam spots as spot_world or spot_camera: world or camera.")
    ] = "world",
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    out: Annotated[Path, typer.Option("--out", "-o", help="Dataset JSON to write.")] = Path(
        "data.json"
    ),
) -> None:
    """Generate a synthetic dataset from the scenario's true geometry."""
    import numpy as np

    from planner.calibration import simulate as sim
    from planner.calibration.dataset import beam_json, handeye_json, write_json
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.model.transforms import matrix_to_quat

    _check_simulate_options(kind, mode, spots, noise, poses, boards, outliers)
    scn = load_scenario(scenario)
    nominal = system_from_scenario(scn)
    truth = system_from_scenario(scn, truth=True)
    name = robot or truth.robot_names[0]
    if name not in truth.robot_names:
        raise InputError(f"--robot {name!r}: scenario robots are {', '.join(truth.robot_names)}")
    rng = np.random.default_rng(seed)
    model = None
    if noise == "d435":  # the D435 model of the feature measured: laser spots or board corners
        from dataclasses import replace

        from planner.model import d435

        fx = truth.camera.intrinsics.fx if truth.camera is not None else d435.FOCAL_PX
        feature = d435.SPOT if kind == "beam" else d435.CORNER
        model = replace(feature.with_focal(fx), outliers=outliers)
    if kind == "beam":
        aim = targets_from_scenario(scn, nominal).points.mean(axis=0)
        data = sim.simulate_beam(truth, name, poses, boards, aim_world=aim, noise=model, rng=rng)
        write_json(out, beam_json(data, truth, spots=spots))
        typer.echo(f"{len(data.q)} spots ({spots} frame) on {boards} boards -> {out}")
        typer.echo(f"next: beamrelay calibrate beam {out} -s {scenario} -o beam.yaml")
        return
    cam_pose, board_pose = sim.default_handeye_truth(truth, name, mode)
    hd = sim.simulate_handeye(
        truth, name, mode, poses, camera_pose=cam_pose, board_pose=board_pose, noise=model, rng=rng
    )
    write_json(out, handeye_json(hd))
    keys = (
        ("world_T_camera", "flange_T_board")
        if mode == "eye_to_hand"
        else ("flange_T_camera", "world_T_board")
    )
    for key, T in zip(keys, (cam_pose, board_pose), strict=True):
        typer.echo(
            f"true {key}: xyz {np.round(T[:3, 3], 6).tolist()} quat {np.round(matrix_to_quat(T[:3, :3]), 6).tolist()}"
        )
    typer.echo(f"{len(hd.q)} {mode} samples -> {out}")
    typer.echo(f"next: beamrelay calibrate handeye {out} -s {scenario} -o handeye.yaml")
