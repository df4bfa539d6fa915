"""``make demo``: the main job on the simulated system, step by step, as a user would run it.

Usage: ``python -m planner.demo OUT_DIR``. Each step is a real ``beamrelay`` command (so the
output is what a user sees); the last step runs the live loop (planner + simulated drivers
over Zenoh) for a few seconds.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from rich.console import Console
from rich.rule import Rule

from planner.data import scenarios_dir
from planner.demo_live import run_live_demo
from planner.verify.safety_report import keep_out_summary

SCENARIOS = scenarios_dir()


def _run(console: Console, title: str, args: list[str], ok: tuple[int, ...] = (0,)) -> None:
    console.print(Rule(f"[bold]{title}"))
    console.print(f"$ beamrelay {' '.join(args)}", style="dim")
    status = subprocess.call([sys.executable, "-m", "planner.cli", *args])
    if status not in ok:
        console.print(f"[red]step failed with exit status {status}[/]")
        sys.exit(status)


def main(out: Path) -> None:
    console = Console()
    out.mkdir(parents=True, exist_ok=True)
    n1, n2, curve = (SCENARIOS / f for f in ("paper_n1.yaml", "n2_relay.yaml", "curve_path.yaml"))
    _run(
        console,
        "1. validate the shipped scenarios",
        ["validate", *map(str, sorted(SCENARIOS.glob("*.yaml")))],
    )
    _run(console, "2. trace the beam at the home pose", ["trace", str(n1)])
    _run(
        console,
        "3. plan the paper's 1000-point grid (N = 1)",
        ["plan", str(n1), "-o", str(out / "plan_n1.json"), "--plot", str(out / "plan_n1.png")],
    )
    _run(console, "4. re-verify it with plain numpy", ["check", str(out / "plan_n1.json")])
    _run(
        console,
        "5. relay through two robots (N = 2)",
        ["plan", str(n2), "-o", str(out / "plan_n2.json"), "--plot", str(out / "plan_n2.png")],
    )
    _run(console, "6. re-verify the N = 2 plan", ["check", str(out / "plan_n2.json")])
    _run(
        console,
        "7. sweep the spot along a vessel-like curve at 20 mm/s",
        [
            "plan",
            str(curve),
            "-o",
            str(out / "plan_curve.json"),
            "--plot",
            str(out / "plan_curve.png"),
        ],
    )
    _run(console, "8. re-verify the path trajectory", ["check", str(out / "plan_curve.json")])
    _safety_steps(console, out)

    console.print(Rule("[bold]11. the running system: planner + simulated drivers over Zenoh"))

    run_live_demo(n1, seconds=5)
    console.print(Rule("[bold green]demo done"))
    console.print(f"outputs in {out}/: plan_*.json (plan.json) and plan_*.png")


def _safety_steps(console: Console, out: Path) -> None:
    """Two arms sharing space, and a face whose eyes the beam must never enter."""
    shared, face = SCENARIOS / "n2_shared.yaml", SCENARIOS / "face_keepout.yaml"
    plan_shared, plan_face = out / "plan_shared.json", out / "plan_face.json"
    _run(
        console,
        "9. two arms sharing space (N = 2, 20 mm arm-arm clearance)",
        ["plan", str(shared), "-o", str(plan_shared), "--plot", str(out / "plan_shared.png")],
    )
    _run(console, "   re-verify it (independent numpy geometry)", ["check", str(plan_shared)])
    # exit status 1: the targets inside the eyes fail as keep_out, as they must
    _run(console, "10. a face with keep-out eyes (targets inside an eye fail as keep_out)",
         ["plan", str(face), "-o", str(plan_face), "--plot", str(out / "plan_face.png")],
         ok=(0, 1))  # fmt: skip
    _run(console, "    re-verify it (independent numpy geometry)", ["check", str(plan_face)])

    from rich.table import Table

    table = Table(title="keep-out volumes of the face plan (numpy re-check)")
    for col in ("volume", "targets inside", "failed keep_out", "beam min (mm)",
                "laser-on samples", "laser-on min (mm)"):  # fmt: skip
        table.add_column(col)
    for row in keep_out_summary(json.loads(plan_face.read_text())):
        table.add_row(row["volume"], str(row["targets_inside"]), str(row["failed_keep_out"]),
                      f"{1e3 * row['beam_min_m']:.1f}", str(row["laser_on_samples"]),
                      f"{1e3 * row['laser_on_min_m']:.1f}")  # fmt: skip
    console.print(table)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "demo-out"))
