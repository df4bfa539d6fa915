"""``beamrelay bench camera``: camera-frame targets under a miscalibrated camera pose.

The in-process world of :mod:`planner.bench.servo_world` (``paper_n1`` as the calibrated
model; a truth with the laser tilted 0.4 deg and the mirror mount 3 mm further out) with the
true camera also displaced from its calibrated pose by ``mm`` along and ``deg`` about random
directions (per trial). Targets are points of the board as the *true* camera sees them
(camera frame, with the board's normal), sent as a ``frame: camera`` request through the
node's request handler: mapped with the calibrated camera pose, landed on the board
(:mod:`planner.plan.landing`), solved. Figures per camera error: the landing offset, the
open-loop true error (the truth's spot at the planned joints vs the true board point), the
closed-loop measured error (camera frame) and true error after the servo
(:func:`planner.servo.servo` on the simulated D435 from the open-loop joints).
"""

from __future__ import annotations

import json
from typing import Annotated, Any

import numpy as np
import typer

#: (mm, deg) camera pose errors of the figures
CASES = ((2.0, 0.2), (5.0, 0.5), (10.0, 1.0))


def trial(mm: float, deg: float, n: int, seed: int, beam: bool = True) -> list[dict[str, float]]:
    """One world with the camera ``mm`` / ``deg`` off (and, with ``beam``, the laser and
    mirror mount) and ``n`` board targets: per solved target its landing offset, open-loop
    true error, closed-loop measured and true error (m)."""
    from planner.bench.servo_world import UP, SimWorld, board_targets, camera_error
    from planner.bench.servo_world import perturbed_scenario as scenario
    from planner.io.scenario import scene_model
    from planner.model.transforms import inv_T, transform_points
    from planner.service.handler import RequestHandler, make_plan_fn
    from planner.servo import Corrector, servo
    from schemas.messages import TargetRequest

    error = camera_error(mm, deg, seed)
    world = SimWorld(scenario(camera_error=error) if beam else scenario(0.0, 0.0, error), seed=seed)
    assert world.truth.camera is not None
    camera_T_world = inv_T(world.truth.camera.world_T_camera)
    P = board_targets(n, seed)
    n_c = camera_T_world[:3, :3] @ UP
    req = TargetRequest.model_validate({
        "schema": "beamrelay.request/1", "id": "bench", "frame": "camera",
        "points": transform_points(camera_T_world, P).tolist(), "normals": [n_c.tolist()] * n,
    })  # fmt: skip
    handler = RequestHandler(world.model, make_plan_fn(world.model, {}, scene=scene_model(world.scenario)))  # fmt: skip
    targets = handler.targets(req)
    plan = handler.plan_fn(targets, None, False)
    corrector = Corrector(world.model)
    rows = []
    for k, sol in enumerate(plan.solutions):
        if not sol.ok:
            continue
        q = world.model.stack_q(dict(sol.q))
        open_spot = world.true_spot(q)
        res = servo(world.measure, q, targets.points[k], targets.normal(k), corrector)
        closed_spot = world.true_spot(res.q)
        rows.append({
            "offset": abs(sol.surface.offset_m) if sol.surface is not None else 0.0,
            "open": np.nan if open_spot is None else float(np.linalg.norm(open_spot - P[k])),
            "measured_after": res.error_after,
            "closed": np.nan if closed_spot is None else float(np.linalg.norm(closed_spot - P[k])),
            "converged": float(res.converged),
        })  # fmt: skip
    return rows


def figures(trials: int, n: int, seed: int, beam: bool = True) -> list[dict[str, Any]]:
    """Per camera error of :data:`CASES`: medians and maxima over ``trials`` x ``n`` targets."""
    out = []
    for mm, deg in CASES:
        rows = [r for t in range(trials) for r in trial(mm, deg, n, seed + t, beam)]
        fig: dict[str, Any] = {"camera_mm": mm, "camera_deg": deg, "targets": len(rows),
                               "converged": int(sum(r["converged"] for r in rows))}  # fmt: skip
        for key in ("offset", "open", "measured_after", "closed"):
            v = np.array([r[key] for r in rows], dtype=float)
            fig[f"{key}_median_m"] = float(np.nanmedian(v)) if len(v) else None
            fig[f"{key}_max_m"] = float(np.nanmax(v)) if len(v) else None
        out.append(fig)
    return out


def command(
    trials: Annotated[int, typer.Option("--trials", min=1, max=50, help="Worlds per case.")] = 2,
    targets: Annotated[int, typer.Option("--targets", min=1, max=100, help="Per world.")] = 4,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Camera errors, targets, noise.")] = 0,
    camera_only: Annotated[
        bool, typer.Option("--camera-only", help="The laser and mirror mount exact.")
    ] = False,
    json_out: Annotated[bool, typer.Option("--json", help="Figures as one JSON line.")] = False,
) -> None:
    """Camera-frame targets with the camera 2/5/10 mm and 0.2/0.5/1 deg off: open and
    closed loop true errors."""
    from rich.console import Console

    figs = figures(trials, targets, seed, beam=not camera_only)
    c = Console()
    beam = "laser and mount exact" if camera_only else "truth laser +0.4 deg, mount +3 mm"
    c.print(f"bench camera: frame-camera board targets; {beam}, camera off as below "
            "(mm: true error median / max)")  # fmt: skip

    def mm(x: float | None) -> str:
        return "-" if x is None else f"{1e3 * x:.2f}"

    for f in figs:
        c.print(f"camera {f['camera_mm']:g} mm / {f['camera_deg']:g} deg: "
                f"{f['converged']}/{f['targets']} converged; landing offset "
                f"{mm(f['offset_median_m'])} / {mm(f['offset_max_m'])}; open loop "
                f"{mm(f['open_median_m'])} / {mm(f['open_max_m'])}; closed loop "
                f"{mm(f['closed_median_m'])} / {mm(f['closed_max_m'])} (measured "
                f"{mm(f['measured_after_median_m'])} / {mm(f['measured_after_max_m'])})")  # fmt: skip
    if json_out:
        print(json.dumps({"cases": figs, "camera_only": camera_only}))
