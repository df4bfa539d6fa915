"""``beamrelay bench track``: spot error on a moving target and the frame -> setpoint latency,
simulated in-process by :mod:`planner.simcell.tracking` (see there for the cell and the
cases). Figures are printed, not asserted.
"""

from __future__ import annotations

import json
from typing import Annotated

import typer

from planner.simcell.tracking import CASES, run_case


def command(
    seconds: Annotated[
        float, typer.Option("--seconds", min=2.0, help="Simulated s per case.")
    ] = 12.0,
    seed: Annotated[int, typer.Option("--seed", help="Noise seed.")] = 0,
    latency: Annotated[
        float, typer.Option("--latency", min=0.0, max=0.033, help="Tracker latency, s.")
    ] = 0.02,
    robot_error: Annotated[
        str, typer.Option("--robot-error", help="True arm's DH error: none, factory, uncalibrated.")
    ] = "none",
    servo_lag: Annotated[
        bool, typer.Option("--servo-lag/--no-servo-lag", help="The arm lags as servoJ does.")
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="One JSON object on the last line.")
    ] = False,
) -> None:
    """Spot error on a moving target (linear 20 mm/s, breathing 5 mm at 0.25 Hz, a turning
    face with keep-out eyes), the frame -> setpoint latency and the setpoint checks' cost,
    simulated in-process; optionally with a true arm off the planner's model and servo lag."""
    from planner.errors import InputError
    from planner.model.kinematic_error import LEVELS

    if robot_error not in LEVELS:
        raise InputError(f"choose one of {', '.join(LEVELS)}, not {robot_error!r}", "--robot-error")
    figures = {name: run_case(m, seconds, seed, latency, scenario, robot_error, servo_lag)
               for name, (scenario, m) in CASES.items()}  # fmt: skip
    for name, f in figures.items():
        mm = {k: (None if v is None else 1e3 * v) for k, v in f.items() if k.endswith("_m")}
        lit = ("never lit" if mm["rms_laser_on_m"] is None else
               f"laser-on RMS {mm['rms_laser_on_m']:.3f} mm, p95 {mm['p95_laser_on_m']:.3f} mm")  # fmt: skip
        typer.echo(
            f"{name:10s} {lit}"
            f" (all: RMS {mm['rms_all_m']:.3f}, p95 {mm['p95_all_m']:.3f}, max"
            f" {mm['max_all_m']:.3f} mm); laser on {100 * f['laser_on_fraction']:.1f} %;"
            f" frame -> setpoint p50 {1e3 * f['latency_p50_s']:.2f} ms,"
            f" p99 {1e3 * f['latency_p99_s']:.2f} ms (processing p99"
            f" {1e3 * f['processing_p99_s']:.2f} ms, CPU p50 {1e3 * f['cpu_p50_s']:.2f} ms);"
            f" setpoint checks {f['checks_per_cpu_s']:.0f}/s of CPU, added per setpoint p50"
            f" {1e3 * f['check_p50_s']:.3f} ms, p99 {1e3 * f['check_p99_s']:.3f} ms"
            f" (CPU p50 {1e3 * f['check_cpu_p50_s']:.3f} ms, p99 {1e3 * f['check_cpu_p99_s']:.3f} ms)"
        )
    if as_json:
        typer.echo(json.dumps(figures))
