"""``beamrelay plan`` and ``beamrelay check`` (light imports only at module level)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from planner.errors import InputError
from planner.model.status import evidence_text

if TYPE_CHECKING:
    from planner.io.plan import Plan


def _fmt(x: float | None, scale: float, digits: str) -> str:
    return "-" if x is None else format(scale * x, digits)


def _plot_format(plot: Path) -> None:
    """Refuse a ``--plot`` file whose extension matplotlib cannot write (before planning)."""
    from matplotlib.figure import Figure

    formats = Figure().canvas.get_supported_filetypes()
    ext = plot.suffix.lower().lstrip(".")
    if ext not in formats:
        raise InputError(
            f"cannot draw {plot.name!r}: use one of {', '.join('.' + f for f in sorted(formats))}",
            "--plot",
        )
    if plot.parent and not plot.parent.exists():
        raise InputError(f"directory does not exist: {plot.parent}", "--plot")


def plan(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="plan.json to write.")],
    optimal: Annotated[
        bool, typer.Option("--optimal", help="IPOPT optimality step after the closed form.")
    ] = False,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Also draw a 3D picture (PNG/PDF/SVG).")
    ] = None,
) -> None:
    """Plan every target of a scenario, time the trajectory, write plan.json, then run the
    checks of 'beamrelay check' on what was written; exit 1 if any target failed or any
    check is violated."""

    from rich.console import Console

    from planner.io.plan_file import read_plan, write_plan
    from planner.plan.pipeline import run_scenario
    from planner.verify.check import check_plan

    if out.parent and not out.parent.exists():
        raise InputError(f"output directory does not exist: {out.parent}", "-o")
    if plot is not None:
        _plot_format(plot)
    outcome = run_scenario(scenario, optimal=optimal)
    plan = outcome.plan
    with out.open("w") as fh:
        write_plan(outcome.doc, fh)
    console = Console()
    console.print(_summary(plan, scenario.name))
    if any(not sol.ok for sol in outcome.solutions):
        console.print(_failures(outcome.solutions))
    if outcome.timed is not None and outcome.timed.trajectory.slowdowns:
        console.print(_slowdowns(outcome))
    console.print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    if plot is not None:
        from planner.plot import plot_plan, plot_profiles, profiles_path

        plot_plan(outcome.system, outcome.targets, outcome.doc, plot)
        console.print(f"wrote {plot}")
        if plan.trajectory is not None:
            plot_profiles(outcome.system, outcome.targets, outcome.doc, profiles_path(plot))
            console.print(f"wrote {profiles_path(plot)}")
    failed = plan.metrics.n_ok < plan.metrics.n_targets
    del outcome, plan  # the check reads the file back: one copy of a large plan in memory
    written = read_plan(out)
    violations = _print_findings(console, check_plan(written, out.parent), "check of the plan")
    if failed or violations:
        raise SystemExit(1)  # planner.cli.main drops typer.Exit codes (non-standalone click)


def _print_findings(console: Any, results: list[Any], title: str, most: int = 20) -> int:
    """Print the violations (the first ``most``) and warnings of check results; returns the
    number of violations."""
    for r in results:
        for w in r.warnings:
            console.print(f"[yellow]{r.name}: {w}")
    findings = [f for r in results for f in r.findings]
    for f in findings[:most]:
        where = f"{f.check}" if f.target is None else f"target {f.target}: {f.check}"
        console.print(f"[red]{where}: {f.message}", highlight=False)
    if len(findings) > most:
        console.print(f"[red]... and {len(findings) - most} more violations")
    if findings:
        console.print(f"[red]{title}: {len(findings)} violation(s)")
    else:
        console.print(f"[green]{title}: OK[/]")
    return len(findings)


def _failures(solutions: list[Any], most: int = 8) -> Any:
    """The first failed targets with their reason and the numbers that show it."""
    from rich.table import Table

    failed = [(k, s) for k, s in enumerate(solutions) if not s.ok]
    table = Table(title=f"failed targets (first {min(most, len(failed))} of {len(failed)})")
    for col in ("target", "reason", "evidence"):
        table.add_column(col)
    for k, sol in failed[:most]:
        table.add_row(str(k), str(sol.reason), evidence_text(dict(sol.evidence or {})))
    return table


def _summary(plan: Plan, fallback_name: str) -> Any:
    """The plan summary table: targets, failures, errors, solve times, trajectory figures."""
    from rich.table import Table

    m, x = plan.metrics, plan.metrics.extra
    table = Table(title=f"plan: {plan.resolved.name or fallback_name}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    table.add_row("targets", str(m.n_targets))
    table.add_row("solved", str(m.n_ok))
    for key, count in sorted(x.items()):
        if key.startswith("failed_"):
            table.add_row(f"failed: {key[7:]}", f"[red]{int(count)}[/]")
    table.add_row("error median (mm)", _fmt(m.error_median, 1e3, ".3g"))
    table.add_row("error max (mm)", _fmt(m.error_max, 1e3, ".3g"))
    table.add_row("solve time median (ms)", _fmt(m.solve_time_median, 1e3, ".3f"))
    table.add_row("solve time p95 (ms)", _fmt(m.solve_time_p95, 1e3, ".3f"))
    if m.duration is None:
        table.add_row("trajectory", "none (nothing solved)")
        return table
    table.add_row("trajectory duration (s)", f"{m.duration:.2f}")
    if "path_time" in x:
        speed = plan.resolved.trajectory.spot_speed
        ideal = x["path_length"] / speed
        table.add_row("  on the path (s)", f"{x['path_time']:.2f} (length/speed {ideal:.2f})")
        table.add_row("  path length (mm)", f"{1e3 * x['path_length']:.1f}")
        table.add_row("  max spot deviation (mm)", f"{1e3 * x['path_deviation_max']:.4f}")
        if "path_joint_speed_max_ratio" in x:
            table.add_row(
                "  max joint speed on the path", f"{100 * x['path_joint_speed_max_ratio']:.1f} %"
            )
        table.add_row("  slowdowns (a limit binds)", str(int(x["slowdowns"])))
    if "duration_given_order" in x:
        table.add_row("  given order, estimate (s)", f"{x['duration_given_order']:.2f}")
        table.add_row("  chosen order, estimate (s)", f"{x['duration_chosen_order']:.2f}")
    table.add_row("  max joint speed (% of limit)", f"{100 * x['joint_speed_max_ratio']:.1f} %")
    table.add_row(
        "  max joint acc. (% of limit)", f"{100 * x['joint_acceleration_max_ratio']:.1f} %"
    )
    return table


def _slowdowns(outcome: Any) -> Any:
    """Where the spot runs slower than requested along the path, and which limit binds."""
    from rich.table import Table

    names = [f"{r.name}.{j}" for r in outcome.system.robots for j in r.kinematics.joint_names]
    table = Table(title="slowdowns: a joint limit binds")
    for col in ("arc length (mm)", "limit", "joint", "spot speed (mm/s)"):
        table.add_column(col)
    for s in outcome.timed.trajectory.slowdowns:
        table.add_row(f"{1e3 * s.s0:.1f} - {1e3 * s.s1:.1f}", s.limit,
                      names[s.joint] if s.joint >= 0 else "-",
                      f"{1e3 * s.speed:.2f}")  # fmt: skip
    return table


#: check figures that are finite-difference joint rates over their limits
_RATE_RATIOS = ("velocity_max_ratio", "acceleration_max_ratio", "jerk_max_ratio")


def _figure_text(key: str, value: float) -> str:
    """A check figure with its unit, lengths in mm (the names of the JSON figures are SI)."""
    if key.endswith("_m"):
        return f"{key[:-2].replace('_', ' ')} {1e3 * value:.3g} mm"
    for suffix, unit in (("_rad", "rad"), ("_deg", "deg"), ("_s", "s")):
        if key.endswith(suffix):
            return f"{key[: -len(suffix)].replace('_', ' ')} {value:.4g} {unit}"
    if key in _RATE_RATIOS:
        from planner.verify.tolerances import RATE_SLACK

        text = f"{key[:-10]} max {100 * value:.1f} % of limit"
        if value > 1:  # the verdict allows finite differences this far over the limit
            text += f" (within the {100 * RATE_SLACK:g} % finite-difference allowance)"
        return text
    if key.endswith("_ratio"):
        return f"{key[:-6].replace('_', ' ')} {100 * value:.1f} %"
    return f"{key.replace('_', ' ')} {value:.3g}"


def check(
    plan_file: Annotated[Path, typer.Argument(help="plan.json to re-verify.")],
    json_out: Annotated[
        bool, typer.Option("--json", help="Figures (SI units) as one JSON object, last line.")
    ] = False,
) -> None:
    """Re-verify a plan with plain numpy (own FK and reflection): solved targets, the
    trajectory sampled at its rate (limits, declared velocities, spot on the path and on
    every target) and the metrics; exit 1 on any violation."""
    import json

    from rich.console import Console
    from rich.table import Table

    from planner.io.plan import Plan
    from planner.io.plan_file import load_plan
    from planner.verify.check import check_plan

    plan_doc = load_plan(plan_file)
    results = check_plan(plan_doc, plan_file.parent)
    console = Console()
    table = Table(title=f"check: {plan_file}")
    for col in ("check", "checked", "violations", "figures"):
        table.add_column(col)
    for r in results:
        figs = ", ".join(_figure_text(k, v) for k, v in r.figures.items())
        bad = f"[red]{len(r.findings)}[/]" if r.findings else "0"
        table.add_row(r.name, str(r.checked), bad, figs)
    console.print(table)
    n_failed = sum(not s.ok for s in Plan.from_document(plan_doc).solutions)
    if n_failed:
        console.print(f"{n_failed} target(s) unsolved in the plan (reported, not checked)")
    violations = _print_findings(console, results, "plan")
    if json_out:
        figures: dict[str, Any] = {"violations": violations, "unsolved": n_failed}
        for r in results:
            figures.update({f"{r.name}.{k}": v for k, v in r.figures.items()})
        print(json.dumps(figures))
    if violations:
        raise SystemExit(1)  # planner.cli.main drops typer.Exit codes (non-standalone click)
