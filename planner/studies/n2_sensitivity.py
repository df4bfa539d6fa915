"""Sensitivity of the relay's spot to each mirror's error (the N = 2 part of paper Fig. 4).

The method of :mod:`planner.studies.sensitivity` on ``scenarios/n2_relay.yaml``: the
scenario's 32 grid targets solved with the NOMINAL relay (the product's
:class:`planner.ik.BeamIK`, from home), then traced with a PERTURBED relay. Six groups,
each a 3-vector with components ``U(-1, 1) x level``, applied as
:func:`planner.studies.sensitivity.perturb` does:

- ``laser_rot`` / ``laser_pos``: the laser (laser frame / world frame);
- ``mirror1_rot`` / ``mirror1_pos``: arm0's mirror (mirror frame / flange frame);
- ``mirror2_rot`` / ``mirror2_pos``: arm1's mirror, likewise;

at the N = 1 study's levels. Spot error: distance from the target to the perturbed last ray
(no normal). Next to it the first-order prediction ``|J delta|`` with J from the CasADi
beam graph (:func:`planner.studies.sensitivity.jacobians`, columns 6 + 6 i of mirror i) and
its expected RMS ``level ||J||_F / sqrt(3)``; ``per_unit`` divides that RMS by the level:
mm of spot error per degree or per millimetre of that mirror's error, which says which mirror
to calibrate best. Units: mm and degrees in the rows, SI inside.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.studies import sensitivity as n1
from planner.studies.sensitivity import Nominal

GROUPS: dict[str, tuple[str, int, slice]] = {
    "laser_rot": ("laser_rot", 0, slice(0, 3)),
    "laser_pos": ("laser_pos", 0, slice(3, 6)),
    "mirror1_rot": ("mirror_rot", 0, slice(6, 9)),
    "mirror1_pos": ("mirror_pos", 0, slice(9, 12)),
    "mirror2_rot": ("mirror_rot", 1, slice(12, 15)),
    "mirror2_pos": ("mirror_pos", 1, slice(15, 18)),
}
"""Group -> (the N = 1 perturbation it applies, the robot whose mirror, its J columns)."""


def solve_nominal() -> Nominal:
    """The scenario's grid targets solved on the nominal relay, with their Jacobians."""
    from planner.io.scenario import targets_from_scenario
    from planner.studies import n2_setup

    system = n2_setup.nominal_system()
    targets = targets_from_scenario(n2_setup.scenario_model(), system).points
    return n1.solve_nominal(system, np.asarray(targets, dtype=float))


def draw(group: str, level: float, seed: int, trial: int) -> np.ndarray:
    """The perturbation (SI) of ``group`` at ``level`` (deg or mm) in one trial."""
    gi, li = list(GROUPS).index(group), n1.levels(group).index(level)
    rng = np.random.default_rng([seed, trial, gi, li])
    return rng.uniform(-1.0, 1.0, 3) * n1.level_si(group, level)


def trial_rows(nominal: Nominal, trial: int, seed: int) -> list[dict[str, Any]]:
    """Every group and level of one trial: sampled and predicted spot errors per target."""
    from planner.beam.graph import BeamModel

    rows = []
    for group, (kind, robot, cols) in GROUPS.items():
        for lvl in n1.levels(group):
            delta = draw(group, lvl, seed, trial)
            model = BeamModel(n1.perturb(nominal.system, kind, delta, robot))
            for k in np.flatnonzero(nominal.solved):
                tr = model.trace(nominal.q[k], nominal.targets[k])
                pred = float(np.linalg.norm(nominal.J[k][:, cols] @ delta))
                rows.append({"trial": trial, "group": group, "level": lvl,
                             "target": int(k), "error_mm": 1e3 * tr.error,
                             "predicted_mm": 1e3 * pred, "valid": int(tr.valid)})  # fmt: skip
    return rows


def predicted_rms_mm(nominal: Nominal, group: str, level: float) -> float:
    """Expected RMS of the first-order error over targets and draws: level ||J||_F / sqrt 3."""
    J = nominal.J[nominal.solved][:, :, GROUPS[group][2]]
    fro2 = np.sum(J**2, axis=(1, 2))
    return float(1e3 * n1.level_si(group, level) * np.sqrt(np.mean(fro2) / 3))


def summarize(nominal: Nominal, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per group and level: sampled and predicted statistics (mm)."""
    out = []
    for group in GROUPS:
        unit = "deg" if n1.is_rotation(group) else "mm"
        for lvl in n1.levels(group):
            sel = [r for r in rows if r["group"] == group and r["level"] == lvl]
            e = np.array([r["error_mm"] for r in sel])
            p = np.array([r["predicted_mm"] for r in sel])
            rms = predicted_rms_mm(nominal, group, lvl)
            out.append({"group": group, "level": f"{lvl:g} {unit}", "mean_mm": float(e.mean()),
                        "rms_mm": float(np.sqrt(np.mean(e**2))), "max_mm": float(e.max()),
                        "pred_rms_mm": rms, "per_unit": rms / lvl, "unit": unit,
                        "rel_dev": float(np.max(np.abs(p - e)) / max(e.max(), 1e-12)),
                        "valid_frac": float(np.mean([r["valid"] for r in sel]))})  # fmt: skip
    return out


def table(summary: list[dict[str, Any]]) -> list[str]:
    """The report's markdown table of :func:`summarize`."""
    from planner.studies.common import table_lines

    header = ["group", "level", "mean (mm)", "RMS (mm)", "max (mm)", "pred RMS (mm)",
              "mm per unit", "max rel dev", "valid ROI"]  # fmt: skip
    row = "{group} | {level} | {mean_mm:.3f} | {rms_mm:.3f} | {max_mm:.3f} | {pred_rms_mm:.3f}"
    row += " | {per_unit:.3f}/{unit} | {rel_dev:.1e} | {valid_frac:.0%}"
    return table_lines(header, summary, row)


TARGETS_TEXT = "4 x 4 x 2 grid of 32 targets (60 x 100 x 50 mm)"
"""The targets, as the report names them (``targets.grid`` of scenarios/n2_relay.yaml)."""


def verdict(summary: list[dict[str, Any]], rot_deg: float, pos_mm: float) -> str:
    """One paragraph: which mirror's errors move the spot most, per unit and at the given
    error levels (deg of tilt, mm of offset: e.g. the unknowns before calibration)."""
    per = {s["group"]: s["per_unit"] for s in summary}
    parts, at = [], []
    for kind, unit in (("rot", "deg"), ("pos", "mm")):
        a, b = per[f"mirror1_{kind}"], per[f"mirror2_{kind}"]
        worst = "mirror 1" if a > b else "mirror 2"
        parts.append(f"per {unit}, mirror 1 moves the spot {a:.2f} mm RMS and mirror 2 "
                     f"{b:.2f} mm ({worst} {max(a, b) / min(a, b):.1f}x)")  # fmt: skip
    for m in (1, 2):
        rot, pos = per[f"mirror{m}_rot"] * rot_deg, per[f"mirror{m}_pos"] * pos_mm
        at.append(f"mirror {m} {rot:.2f} mm from its tilt and {pos:.2f} mm from its offset")
    return (
        f"First order, {'; '.join(parts)}. At ±{rot_deg:g} deg / ±{pos_mm:g} mm per "
        f"component: {'; '.join(at)}."
    )
