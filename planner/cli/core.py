"""``beamrelay validate`` and ``beamrelay trace``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from planner.cli.args import parse_xyz
from planner.errors import InputError


def validate(
    files: Annotated[list[Path], typer.Argument(help="Scenarios, datasets, plans, requests.")],
) -> None:
    """Check scenarios, datasets, plans and requests against their schemas. Exit 2 on any error."""
    from planner.io.validate import validate_file

    bad = 0
    for path in files:
        try:
            kind, _ = validate_file(path)
        except InputError as exc:
            typer.echo(f"error: {exc}", err=True)
            bad += 1
        else:
            typer.echo(f"{path}: OK ({kind})")
    if bad:
        raise typer.Exit(2)


def _parse_q(specs: list[str]) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for spec in specs:
        name, sep, values = spec.partition("=")
        if not sep:
            raise InputError(f"--q {spec!r}: expected ROBOT=q1,...,q6")
        try:
            out[name.strip()] = [float(x) for x in values.split(",")]
        except ValueError as exc:
            raise InputError(f"--q {spec!r}: joint values must be numbers") from exc
    return out


def check_radians(name: str, q: Any, lower: Any, upper: Any) -> None:
    """Refuse joint values (rad) of robot ``name`` outside its position limits, saying so
    when they look like degrees (any beyond 2 pi): one line, InputError."""
    import numpy as np

    outside = np.flatnonzero((q < lower) | (q > upper))
    if not outside.size:
        return
    j = int(outside[0])
    hint = ""
    if np.abs(q).max() > 2 * np.pi:
        hint = (f"; these look like degrees: --q takes radians "
                f"({q[j]:g} deg = {np.radians(q[j]):.4f} rad)")  # fmt: skip
    raise InputError(f"--q {name}: joint {j} = {q[j]:g} rad is outside its limits "
                     f"[{lower[j]:.4f}, {upper[j]:.4f}] rad{hint}")  # fmt: skip


def trace(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML.")],
    q: Annotated[
        list[str] | None,
        typer.Option("--q", help="ROBOT=q1,...,q6 in radians; robots not given stay at home."),
    ] = None,
    target: Annotated[
        str | None, typer.Option(help="X,Y,Z world point: also report the spot error.")
    ] = None,
) -> None:
    """Forward beam model at given joints: hits, (u, v) on each mirror, validity, spot."""
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from planner.beam.graph import BeamModel
    from planner.io.scenario import load_scenario, system_from_scenario
    from planner.model.validity import ahead_ok, front_ok, roi_ok

    scn = load_scenario(scenario)
    system = system_from_scenario(scn)
    given = _parse_q(q or [])
    joints = {}
    for r in system.robots:
        qi = np.asarray(given.pop(r.name, r.home), dtype=float)
        if qi.shape != (r.nq,):
            raise InputError(f"--q {r.name}: expected {r.nq} joint values, got {qi.size}")
        check_radians(r.name, qi, r.limits.lower, r.limits.upper)
        joints[r.name] = qi
    if given:
        names = ", ".join(system.robot_names)
        raise InputError(f"--q: unknown robot {next(iter(given))!r} (robots: {names})")
    p_target = None
    if target is not None:
        p_target = np.array(parse_xyz(target, "--target"))
    model = BeamModel(system)
    tr = model.trace(system.stack_q(joints), p_target)

    console = Console()
    table = Table(title=f"beam trace: {scn.model.name}")
    for col in ("mirror", "hit x y z (m)", "u v (mm)", "front", "ahead", "in ROI"):
        table.add_column(col)
    for i, r in enumerate(system.robots):
        ok_front, ok_ahead, ok_roi = front_ok(tr.front[i]), ahead_ok(tr.ahead[i]), roi_ok(tr.roi[i])
        table.add_row(
            r.name,
            " ".join(f"{x:+.4f}" for x in tr.hits[i]),
            " ".join(f"{1e3 * x:+.2f}" for x in tr.uv[i]),
            "yes" if ok_front else "[red]back face[/]",
            "yes" if ok_ahead else "[red]behind[/]",
            "yes" if ok_roi.all() else "[red]outside[/]",
        )
    console.print(table)
    console.print(f"outgoing direction: {' '.join(f'{x:+.4f}' for x in tr.dirs[-1])}")
    console.print(f"spot (m): {' '.join(f'{x:+.5f}' for x in tr.spot)}")
    if p_target is not None:
        console.print(f"spot error: {1e3 * tr.error:.6f} mm")
    console.print("chain valid" if tr.valid else "[red]chain NOT valid[/]")
    if not tr.valid:
        raise typer.Exit(1)
