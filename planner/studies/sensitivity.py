"""``beamrelay study sensitivity``: paper Fig. 4 — spot error under geometry errors.

64 targets on a 4x4x4 grid in a 20 cm cube are solved with the NOMINAL system (the
product's beam IK, :class:`planner.ik.BeamIK`: its closed-form member, which hits the mirror
centre, each target from home); the joints are then traced with a PERTURBED system. Four groups of perturbation, each a 3-vector with components
``U(−1, 1) × level``:

- ``laser_rot``  rotation vector applied in the laser frame, ``world_T_laser · R(δ)``
- ``laser_pos``  translation of the laser origin in the world frame
- ``mirror_rot`` rotation vector in the mirror frame, ``flange_T_mirror · R(δ)``
- ``mirror_pos`` translation of the mirror centre in the flange frame

at levels Δθ ∈ {0.25, 0.5, 1.0}° and Δp ∈ {2.5, 5, 10} mm. The spot error is the distance
from the target to the perturbed last ray (docs/conventions.md: Beam model, no normal).

Next to the sampled errors the study gives the analytic first-order prediction
``|J δ|`` with ``J = ∂residual/∂δ`` taken from the CasADi beam graph (parameters are graph
inputs), and its expected RMS ``level · ‖J‖_F / √3`` (E[δδᵀ] = level²/3 · I).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from planner.model.system import System
from planner.model.transforms import Array
from planner.studies import common

TRIALS = 10  # paper scale: the default of --trials and of `study all`
GROUPS = ("laser_rot", "laser_pos", "mirror_rot", "mirror_pos")
ROT_LEVELS_DEG = (0.25, 0.5, 1.0)
POS_LEVELS_MM = (2.5, 5.0, 10.0)
CUBE_CENTER = (0.45, 0.15, 0.0)
CUBE_SIZE = 0.2


def is_rotation(group: str) -> bool:
    return group.endswith("_rot")


def level_si(group: str, level: float) -> float:
    """A level as printed (deg or mm) -> SI (rad or m)."""
    return float(np.deg2rad(level)) if is_rotation(group) else level / 1000.0


def levels(group: str) -> tuple[float, ...]:
    return ROT_LEVELS_DEG if is_rotation(group) else POS_LEVELS_MM


def rotvec_matrix(w: Array) -> Array:
    """Rotation matrix of a rotation vector (rad), Rodrigues."""
    from planner.model.transforms import axis_angle_to_matrix

    return axis_angle_to_matrix(np.asarray(w, dtype=float))


def perturb(system: System, group: str, delta: Array, robot: int = 0) -> System:
    """A copy of ``system`` with one perturbation applied (see the module docstring)."""
    delta = np.asarray(delta, dtype=float)
    if group == "laser_rot":
        T = system.world_T_laser.copy()
        T[:3, :3] = T[:3, :3] @ rotvec_matrix(delta)
        return system.with_params(world_T_laser=T)
    if group == "laser_pos":
        T = system.world_T_laser.copy()
        T[:3, 3] += delta
        return system.with_params(world_T_laser=T)
    r = system.robots[robot]
    M = r.mirror.flange_T_mirror.copy()
    if group == "mirror_rot":
        M[:3, :3] = M[:3, :3] @ rotvec_matrix(delta)
    elif group == "mirror_pos":
        M[:3, 3] += delta
    else:
        raise ValueError(f"unknown perturbation group {group!r}; known: {', '.join(GROUPS)}")
    return system.with_params(flange_T_mirror={r.name: M})


def grid_targets(
    center: Sequence[float] = CUBE_CENTER, size: float = CUBE_SIZE, n: int = 4
) -> Array:
    """``n³`` targets on a grid filling a cube (world, metres)."""
    axis = np.linspace(-size / 2, size / 2, n)
    g = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    return g + np.asarray(center, dtype=float)


@lru_cache(maxsize=8)
def sensitivity_function(kinematics: tuple[Any, ...], surfaces: tuple[Any, ...]) -> Any:
    """CasADi function ``J(q, params, target) -> ∂residual/∂δ`` (3 x (6 + 6N)).

    δ = [laser_rot, laser_pos, mirror_rot_0, mirror_pos_0, ...], each 3 components, applied
    as in :func:`perturb`. Built from :func:`planner.beam.graph.beam_chain`, cached per chain.
    """
    import casadi as ca

    from planner.beam.graph import beam_chain, chain_symbols

    N = len(kinematics)
    sym = chain_symbols(kinematics)
    target = ca.SX.sym("target", 3)
    delta = ca.SX.sym("delta", 6 + 6 * N)

    def small_T(w: ca.SX, p: ca.SX) -> ca.SX:
        cx, sx, cy, sy, cz, sz = (f(w[i]) for i in range(3) for f in (ca.cos, ca.sin))
        Rx = ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, cx, -sx), ca.horzcat(0, sx, cx))
        Ry = ca.vertcat(ca.horzcat(cy, 0, sy), ca.horzcat(0, 1, 0), ca.horzcat(-sy, 0, cy))
        Rz = ca.vertcat(ca.horzcat(cz, -sz, 0), ca.horzcat(sz, cz, 0), ca.horzcat(0, 0, 1))
        R = ca.mtimes([Rz, Ry, Rx])  # derivative at 0 is skew(w), as for exp(w)
        return ca.vertcat(ca.horzcat(R, p), ca.horzcat(0, 0, 0, 1))

    zero = ca.SX.zeros(3)
    laser = ca.mtimes(sym.world_T_laser, small_T(delta[0:3], zero))
    laser = laser + ca.vertcat(ca.horzcat(ca.SX.zeros(3, 3), delta[3:6]), ca.SX.zeros(1, 4))
    mounts = []
    for i in range(N):
        d = delta[6 + 6 * i : 12 + 6 * i]
        M_rot = ca.mtimes(sym.mounts[i], small_T(d[0:3], zero))
        mounts.append(M_rot + ca.vertcat(ca.horzcat(ca.SX.zeros(3, 3), d[3:6]), ca.SX.zeros(1, 4)))
    hits, _, dirs, _, _, _ = beam_chain(sym.q, laser, sym.bases, mounts, kinematics, surfaces)
    p, v = hits[-1], dirs[-1]
    residual = p + ca.dot(v, target - p) * v - target
    J = ca.substitute(ca.jacobian(residual, delta), delta, ca.SX.zeros(delta.shape))
    names = ("q", "world_T_laser", "world_T_base", "flange_T_mirror")
    inputs = {name: getattr(sym, name) for name in names} | {"target": target}
    return ca.Function("spot_sensitivity", inputs | {"J": J}, list(inputs), ["J"])


def jacobians(system: System, qs: Array, targets: Array) -> Array:
    """``∂residual/∂δ`` per target, shape (K, 3, 6 + 6N) (metres per rad / per metre)."""
    from planner.beam.graph import system_params

    fn = sensitivity_function(system.kinematics, system.surfaces)
    par = {name: x for name, x in system_params(system).items() if name in fn.name_in()}
    return np.stack(
        [np.asarray(fn(q=q, **par, target=t)["J"]) for q, t in zip(qs, targets, strict=True)]
    )


GROUP_COLUMNS = {"laser_rot": slice(0, 3), "laser_pos": slice(3, 6)}
GROUP_COLUMNS |= {"mirror_rot": slice(6, 9), "mirror_pos": slice(9, 12)}


@dataclass(frozen=True)
class Nominal:
    """Nominal solution of the target set: joints per target (NaN row = unsolved)."""

    system: System
    targets: Array  # (K, 3)
    q: Array  # (K, nq)
    J: Array  # (K, 3, 12)

    @property
    def solved(self) -> Array:
        return np.all(np.isfinite(self.q), axis=1)


def solve_nominal(system: System, targets: Array) -> Nominal:
    """Beam IK (:class:`planner.ik.BeamIK`) of every target from home with the nominal
    system, plus the Jacobians. Targets are independent of each other (any order, any
    executor)."""
    from planner.ik import BeamIK

    ik = BeamIK(system)
    qs = np.full((len(targets), system.nq), np.nan)
    for k, t in enumerate(targets):
        sol = ik.solve(t, None, system.home)
        if sol.q is not None:
            qs[k] = sol.q
    ok = np.all(np.isfinite(qs), axis=1)
    J = np.full((len(targets), 3, 6 + 6 * system.n_robots), np.nan)
    if ok.any():
        J[ok] = jacobians(system, qs[ok], targets[ok])
    return Nominal(system, targets, qs, J)


def trial_rows(nominal: Nominal, trial: int, seed: int) -> list[dict[str, Any]]:
    """Every group and level of one trial: spot errors sampled and predicted, per target."""
    from planner.beam.graph import BeamModel

    rows = []
    for gi, group in enumerate(GROUPS):
        for li, lvl in enumerate(levels(group)):
            rng = np.random.default_rng([seed, trial, gi, li])
            delta = rng.uniform(-1.0, 1.0, 3) * level_si(group, lvl)
            model = BeamModel(perturb(nominal.system, group, delta))
            for k in np.flatnonzero(nominal.solved):
                tr = model.trace(nominal.q[k], nominal.targets[k])
                pred = float(np.linalg.norm(nominal.J[k][:, GROUP_COLUMNS[group]] @ delta))
                rows.append(
                    {
                        "trial": trial,
                        "group": group,
                        "level": lvl,
                        "unit": "deg" if is_rotation(group) else "mm",
                        "target": int(k),
                        "error_mm": 1000 * tr.error,
                        "predicted_mm": 1000 * pred,
                        "valid": int(tr.valid),
                    }
                )
    return rows


def predicted_rms_mm(nominal: Nominal, group: str, lvl: float) -> float:
    """Expected RMS of the first-order error over targets and draws: level·‖J‖_F/√3."""
    J = nominal.J[nominal.solved][:, :, GROUP_COLUMNS[group]]
    fro2 = np.sum(J**2, axis=(1, 2))
    return float(1000 * level_si(group, lvl) * np.sqrt(np.mean(fro2) / 3))


def summarize(nominal: Nominal, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per group and level: sampled and predicted statistics in mm."""
    out = []
    for group in GROUPS:
        for lvl in levels(group):
            sel = [r for r in rows if r["group"] == group and r["level"] == lvl]
            e = np.array([r["error_mm"] for r in sel])
            p = np.array([r["predicted_mm"] for r in sel])
            out.append(
                {
                    "group": group,
                    "level": f"{lvl:g} {'deg' if is_rotation(group) else 'mm'}",
                    "mean_mm": float(e.mean()),
                    "std_mm": float(e.std()),
                    "median_mm": float(np.median(e)),
                    "max_mm": float(e.max()),
                    "rms_mm": float(np.sqrt(np.mean(e**2))),
                    "pred_mean_mm": float(p.mean()),
                    "pred_rms_mm": predicted_rms_mm(nominal, group, lvl),
                    "rel_dev": float(np.max(np.abs(p - e)) / max(e.max(), 1e-12)),
                    "valid_frac": float(np.mean([r["valid"] for r in sel])),
                }
            )
    return out


def default_system() -> System:
    """The paper's N = 1 setup: laser along −x at 0.3 m height."""
    from planner.model.build import build_system
    from planner.model.transforms import make_T, rpy_to_matrix

    laser = make_T(rpy_to_matrix(np.deg2rad([0.0, -90.0, 0.0])), [0.60, -0.40, 0.30])
    return build_system(laser, roi_margin=0.01)


def run(
    trials: int = TRIALS, seed: int = 0, workers: int | None = None, scheduler: str | None = None
) -> tuple[Nominal, list[dict[str, Any]]]:
    """The whole study: nominal solve, then every trial (parallel over trials)."""
    nominal = solve_nominal(default_system(), grid_targets())
    per_trial = common.parallel_map(
        trial_rows,
        [(nominal, t, seed) for t in range(trials)],
        workers=workers,
        scheduler=scheduler,
        label="sensitivity trials",
    )
    return nominal, [r for rows in per_trial for r in rows]


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    """Box plots of the sampled error per group and level, predicted mean marked."""
    plt = common.pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.4), sharey=False)
    for ax, group in zip(axes, GROUPS, strict=True):
        lv = levels(group)
        data = [
            [r["error_mm"] for r in rows if r["group"] == group and r["level"] == x] for x in lv
        ]
        pred = [
            np.mean([r["predicted_mm"] for r in rows if r["group"] == group and r["level"] == x])
            for x in lv
        ]
        ax.boxplot(data, showfliers=True, flierprops={"markersize": 2})
        ax.plot(range(1, len(lv) + 1), pred, "r^", label="first-order mean")
        ax.set_xticks(range(1, len(lv) + 1), [f"{x:g}" for x in lv])
        ax.set_xlabel("level (deg)" if is_rotation(group) else "level (mm)")
        ax.set_title(group.replace("_", " "))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("spot error (mm)")
    axes[0].legend(fontsize=7)
    common.save_figure(fig, path)


def write(out: Path, nominal: Nominal, rows: list[dict[str, Any]], trials: int, seed: int) -> dict:
    """CSV, plot and report.md; returns the figures printed with ``--json``."""
    summary = summarize(nominal, rows)
    plot(rows, common.out_dir(out) / "sensitivity.png")
    lines = [
        "# Sensitivity of the spot to geometry errors (paper Fig. 4)",
        "",
        f"{int(nominal.solved.sum())}/{len(nominal.targets)} targets on a 4x4x4 grid in a "
        f"{CUBE_SIZE * 100:.0f} cm cube centred at {list(CUBE_CENTER)} m, N = 1 UR5e, "
        f"{trials} trials, seed {seed}. Joints solved with the nominal system, traced with the "
        "perturbed one; each perturbation component U(-1, 1) x level.",
        "",
        "The paper shows these as box plots only (Fig. 4, no table); the first-order columns "
        "are ours: `pred mean` = mean of |J δ| for the same draws, `pred RMS` = level·‖J‖_F/√3 "
        "(no sampling), `max rel dev` = max |pred − sampled| / max sampled.",
        "",
    ]
    header = ["group", "level", "mean ± std (mm)", "median", "max", "RMS", "pred mean"]
    header += ["pred RMS", "max rel dev", "valid ROI"]
    row = "{group} | {level} | {mean_mm:.2f} ± {std_mm:.2f} | {median_mm:.2f} | {max_mm:.2f} "
    row += (
        "| {rms_mm:.2f} | {pred_mean_mm:.2f} | {pred_rms_mm:.2f} | {rel_dev:.1e} | {valid_frac:.0%}"
    )
    lines += common.table_lines(header, summary, row)
    tables = {"sensitivity.csv": rows, "summary.csv": summary}
    common.write_report(out, [*lines, ""], tables, image=("box plots", "sensitivity.png"))
    return {"study": "sensitivity", "trials": trials, "seed": seed, "summary": summary}


def main(trials: int, seed: int, out: Path, workers: int | None, sched: str | None) -> dict:
    """Fig. 4: spot error under laser/mirror orientation and position errors."""
    return write(out, *run(trials, seed, workers, sched), trials, seed)


command = common.study_command(main, TRIALS, Path("reports/sensitivity"))
