"""``beamrelay study mirror-sweep``: paper Fig. 5 — error vs mirror mount offset.

Targets are drawn uniformly in the sensitivity study's 20 cm cube (``--trials`` of them,
seeded) and solved with the nominal N = 1 system (:func:`planner.studies.sensitivity.
solve_nominal`: the product's beam IK, whose closed-form member puts the hit point at the
mirror centre, so the mount rotations below turn the mirror about the hit point). The mirror mount is then offset along one
axis at a time, orientation −1..+1° (step 0.2°) and position −10..+10 mm (step 2 mm), and
the spot error (distance from target to the perturbed last ray) is recorded.

The axes are taken per target in the geometry of the reflection, which is what explains the
curves (``v_in``/``v_out`` the beam before/after the mirror, ``i`` the incidence angle,
``L`` the beam length from mirror to target):

- ``tilt_in``: tilt about ``v_in × v_out`` (the beam turns in the plane of incidence by
  ``2Δθ`` about the hit point): error = ``L · sin 2Δθ`` ≈ ``2 Δθ L`` — the lever arm is the
  beam length;
- ``tilt_across``: tilt about the in-plane axis ``n × (v_in × v_out)``: ≈ ``2 Δθ L cos i``;
- ``spin``: about the normal: 0;
- ``normal``: shift along the normal: the hit slides ``Δp / cos i`` along ``v_in`` and the
  ray moves parallel to itself by ``2 Δp sin i``, independent of ``L``;
- ``in_plane_a`` / ``in_plane_b``: shifts inside the mirror plane: 0 (until the ROI is left).

So 1° of tilt at L = 0.5 m moves the spot by 17 mm, while 1 mm of offset moves it at most
2 mm: orientation dominates because its effect scales with the beam length.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from planner.model.transforms import Array
from planner.studies import common
from planner.studies.sensitivity import CUBE_CENTER, CUBE_SIZE, Nominal, perturb

TRIALS = 64  # paper scale: the default of --trials and of `study all`
ROT_AXES = ("tilt_in", "tilt_across", "spin")
POS_AXES = ("normal", "in_plane_a", "in_plane_b")
ROT_OFFSETS_DEG = tuple(np.round(np.arange(-1.0, 1.0001, 0.2), 10))
POS_OFFSETS_MM = tuple(np.round(np.arange(-10.0, 10.001, 2.0), 10))


def reflection_axes(nominal: Nominal, k: int) -> dict[str, Any]:
    """Unit axes of target ``k``'s reflection in the mirror frame, plus ``L`` and ``cos i``."""
    from planner.beam.graph import BeamModel

    model = BeamModel(nominal.system)
    tr = model.trace(nominal.q[k], nominal.targets[k])
    world_T_mirror = model.world_T_mirrors(nominal.q[k])[0]
    R = world_T_mirror[:3, :3]
    v_in, v_out = tr.dirs[0], tr.dirs[1]
    n = R[:, 2]
    a = np.cross(v_in, v_out)
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    return {
        "tilt_in": R.T @ a,
        "tilt_across": R.T @ b,
        "spin": np.array([0.0, 0.0, 1.0]),
        "normal": np.array([0.0, 0.0, 1.0]),
        "in_plane_a": R.T @ a,
        "in_plane_b": R.T @ b,
        "L": float(np.linalg.norm(nominal.targets[k] - tr.hits[0])),
        "cos_i": float(-(n @ v_in)),
    }


def sweep_target(nominal: Nominal, k: int) -> list[dict[str, Any]]:
    """Every axis and offset for target ``k``: measured and predicted spot errors."""
    from planner.beam.graph import BeamModel

    ax = reflection_axes(nominal, k)
    flange_R_mirror = nominal.system.robots[0].mirror.flange_T_mirror[:3, :3]
    L, cos_i = ax["L"], ax["cos_i"]
    rows = []
    for name in (*ROT_AXES, *POS_AXES):
        rot = name in ROT_AXES
        for off in ROT_OFFSETS_DEG if rot else POS_OFFSETS_MM:
            s = np.deg2rad(off) if rot else off / 1000.0
            delta = ax[name] * s if rot else flange_R_mirror @ (ax[name] * s)
            system = perturb(nominal.system, "mirror_rot" if rot else "mirror_pos", delta)
            tr = BeamModel(system).trace(nominal.q[k], nominal.targets[k])
            predicted = {
                "tilt_in": L * abs(np.sin(2 * s)),
                "tilt_across": 2 * abs(s) * L * cos_i,
                "normal": 2 * abs(s) * np.sqrt(max(0.0, 1 - cos_i**2)),
            }.get(name, 0.0)
            rows.append(
                {
                    "target": k,
                    "axis": name,
                    "kind": "rotation" if rot else "position",
                    "offset": float(off),
                    "unit": "deg" if rot else "mm",
                    "error_mm": 1000 * tr.error,
                    "predicted_mm": 1000 * predicted,
                    "beam_length_m": L,
                    "cos_incidence": cos_i,
                    "valid": int(tr.valid),
                }
            )
    return rows


def random_targets(n: int, seed: int) -> Array:
    """``n`` targets uniform in the sensitivity cube (world, metres), seeded."""
    rng = np.random.default_rng([seed, 5])
    return np.asarray(CUBE_CENTER) + rng.uniform(-CUBE_SIZE / 2, CUBE_SIZE / 2, (n, 3))


def run(
    trials: int = TRIALS, seed: int = 0, workers: int | None = None, scheduler: str | None = None
) -> tuple[Nominal, list[dict[str, Any]]]:
    """Solve ``trials`` random targets, then sweep each (parallel over targets)."""
    from planner.studies.sensitivity import default_system, solve_nominal

    nominal = solve_nominal(default_system(), random_targets(trials, seed))
    jobs = [(nominal, int(k)) for k in np.flatnonzero(nominal.solved)]
    per_target = common.parallel_map(
        sweep_target, jobs, workers=workers, scheduler=scheduler, label="mirror sweep"
    )
    return nominal, [r for rows in per_target for r in rows]


def curves(rows: list[dict[str, Any]]) -> dict[str, dict[str, Array]]:
    """Mean measured / predicted error (mm) per axis and offset, and the measured error's
    standard deviation over the targets (``std``, mm; the spread band of Fig. 5)."""
    out: dict[str, dict[str, Array]] = {}
    for name in (*ROT_AXES, *POS_AXES):
        sel = [r for r in rows if r["axis"] == name]
        offs = np.array(sorted({r["offset"] for r in sel}))
        out[name] = {
            "offset": offs,
            "error": np.array(
                [np.mean([r["error_mm"] for r in sel if r["offset"] == o]) for o in offs]
            ),
            "std": np.array(
                [np.std([r["error_mm"] for r in sel if r["offset"] == o]) for o in offs]
            ),
            "predicted": np.array(
                [np.mean([r["predicted_mm"] for r in sel if r["offset"] == o]) for o in offs]
            ),
        }
    return out


def plot(rows: list[dict[str, Any]], mean_L: float, path: Path) -> None:
    """Error vs offset (mean over targets, band = ± one standard deviation), orientation and
    position, with the 2·Δθ·L lever-arm line."""
    plt = common.pyplot()
    c = curves(rows)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6))

    def band(ax: Any, name: str) -> None:
        x, m, sd = c[name]["offset"], c[name]["error"], c[name]["std"]
        (line,) = ax.plot(x, m, "o-", ms=3, label=f"{name} (mean ± std)")
        ax.fill_between(x, np.maximum(m - sd, 0.0), m + sd, color=line.get_color(), alpha=0.2)

    for name in ROT_AXES:
        band(a1, name)
    x = c["tilt_in"]["offset"]
    a1.plot(x, 2 * np.deg2rad(np.abs(x)) * mean_L * 1000, "k--", label=f"2·Δθ·L (L={mean_L:.2f} m)")
    a1.set_xlabel("mirror orientation offset (deg)")
    a1.set_ylabel("spot error (mm), mean ± std over targets")
    for name in POS_AXES:
        band(a2, name)
    x = c["normal"]["offset"]
    a2.plot(x, 2 * np.abs(x), "k--", label="2·Δp (sin i = 1)")
    a2.set_xlabel("mirror position offset (mm)")
    a2.set_ylim(a1.get_ylim())
    for ax in (a1, a2):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    common.save_figure(fig, path)


def slopes(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Least-squares slope of |error| vs |offset| per axis, measured and predicted."""
    out = []
    for name in (*ROT_AXES, *POS_AXES):
        sel = [r for r in rows if r["axis"] == name]
        x = np.abs([r["offset"] for r in sel])
        e = np.array([r["error_mm"] for r in sel])
        p = np.array([r["predicted_mm"] for r in sel])
        unit = sel[0]["unit"]
        out.append(
            {
                "axis": name,
                "unit": f"mm/{unit}",
                "slope": float(x @ e / (x @ x)),
                "predicted_slope": float(x @ p / (x @ x)),
                "max_error_mm": float(e.max()),
                "max_abs_dev_mm": float(np.max(np.abs(e - p))),
            }
        )
    return out


def write(out: Path, nominal: Nominal, rows: list[dict[str, Any]], trials: int, seed: int) -> dict:
    """CSV, plot and report.md; returns the ``--json`` figures."""
    L = np.array(
        [r["beam_length_m"] for r in rows if r["axis"] == "tilt_in" and r["offset"] == 1.0]
    )
    mean_L = float(L.mean())
    plot(rows, mean_L, common.out_dir(out) / "mirror_sweep.png")
    table = slopes(rows)
    c = curves(rows)
    lines = [
        "# Mirror mount sweep (paper Fig. 5)",
        "",
        f"{int(nominal.solved.sum())}/{len(nominal.targets)} random targets in the "
        f"{CUBE_SIZE * 100:.0f} cm cube (seed {seed}), N = 1 UR5e; orientation −1..+1° step "
        "0.2°, position −10..+10 mm step 2 mm, one axis at a time, axes taken in each "
        "target's plane of incidence (see `planner/studies/mirror_sweep.py`).",
        "",
        f"Beam length mirror → target L: mean {mean_L:.3f} m, range {L.min():.3f}–{L.max():.3f} m."
        f" Predicted slope of `tilt_in`: 2·L·π/180 = {2 * mean_L * np.pi / 180 * 1000:.2f} mm/deg;"
        " of a normal shift: 2·sin i ≤ 2 mm/mm.",
        "",
    ]
    header = ["axis", "slope (ours)", "predicted", "max error (mm)"]
    row = "{axis} | {slope:.3f} {unit} | {predicted_slope:.3f} | {max_error_mm:.2f} "
    row += "| {max_abs_dev_mm:.2e}"
    lines += common.table_lines([*header, "max dev. from prediction (mm)"], table, row)
    lines += [
        "",
        "Paper (Fig. 5, plots only): orientation errors of the mirror dominate position "
        "errors. Ours: at the sweep ends, 1° of tilt gives "
        f"{table[0]['max_error_mm']:.1f} mm and 10 mm along the normal gives "
        f"{table[3]['max_error_mm']:.1f} mm: the tilt error grows with the lever arm L, the "
        "shift error does not.",
        "",
        "Spread over the targets (the bands of the plot, mean ± std): "
        + ", ".join(
            f"{name} at {off:g} {unit}: {c[name]['error'][i]:.2f} ± {c[name]['std'][i]:.2f} mm"
            for name, off, unit in (
                ("tilt_in", 1.0, "deg"),
                ("tilt_across", 1.0, "deg"),
                ("normal", 10.0, "mm"),
            )
            for i in [int(np.flatnonzero(c[name]["offset"] == off)[0])]
        )
        + ".",
        "",
    ]
    common.write_report(
        out, lines, {"mirror_sweep.csv": rows}, image=("error vs offset", "mirror_sweep.png")
    )
    return {
        "study": "mirror-sweep",
        "trials": trials,
        "seed": seed,
        "mean_L_m": mean_L,
        "slopes": table,
    }


def main(trials: int, seed: int, out: Path, workers: int | None, sched: str | None) -> dict:
    """Fig. 5: spot error vs mirror orientation / position offset (--trials targets)."""
    return write(out, *run(trials, seed, workers, sched), trials, seed)


command = common.study_command(main, TRIALS, Path("reports/mirror-sweep"))
