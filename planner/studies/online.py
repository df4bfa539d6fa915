"""``beamrelay study online``: open-loop error of the next targets as online samples accrue.

Setup: ``scenarios/paper_n1.yaml`` (N = 1 UR5e, laser, D435 looking at a board) with a
second surface: a block (``BLOCK_EXTENTS``) standing on one half of the board, so samples and
evaluation targets lie on two planes 5 cm apart (a refit needs held-out samples on two
surfaces: one plane cannot tell a tilted laser from a shifted mirror). One trial:

1. the TRUE geometry is the scenario's (nominal) one with the laser turned by
   ``LASER_DEG`` about a random axis across its beam and the mirror mount shifted by
   ``MIRROR_MM`` along its normal (the camera pose is taken as calibrated);
2. the planner solves targets drawn uniformly on the board's free half and on the block's
   top, in turn (with their normals), with the product's :class:`planner.ik.BeamIK` on the
   calibration in force, open loop; the simulated camera
   (:class:`drivers.camera.sim.SimCamera` on the true geometry and both objects, its D435
   spot model) measures the spot at those joints, the planner maps it to the world with its
   camera pose, and the pair, labelled with its surface, is one sample of
   :func:`planner.calibration.online.refit`, which runs after every sample (as the node's
   background thread does) and may refuse;
3. after 0, 5, 10 and 20 samples the next ``N_EVAL`` targets (the same set at every
   checkpoint, half on each surface) are planned open loop with the calibration in force,
   and their true error is the distance on the surface between the true beam's spot and
   the target.

Figures: the mean over the per-trial means of that error with its 95 % CI, and the median
and p95 over the evaluation targets (mm), of the trials that reached each checkpoint (a trial that gave up before it, after ``MAX_MISSES`` targets
without a solution or a seen spot, is counted apart), the fraction of refits accepted, and
the calibration version reached.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.data import shipped_scenario
from planner.model.system import System
from planner.model.transforms import Array, axis_angle_to_matrix, make_T, transform_points
from planner.studies import common
from planner.studies.experiments_metrics import mean_ci

if TYPE_CHECKING:
    from planner.calibration.online import SpotSample

TRIALS = 10  # the default of --trials and of `study all`
CHECKPOINTS = (0, 5, 10, 20)
N_EVAL = 20  # evaluation targets per checkpoint and trial
MAX_MISSES = 200  # targets without a solution or a seen spot before a trial gives up
LASER_DEG = 0.4  # true laser tilt vs the scenario, deg
MIRROR_MM = 3.0  # true mirror-mount shift along its normal vs the scenario, mm
BOARD = "board"  # the scene box the targets lie on
BLOCK = "block"  # the study's second surface, standing on the board's +x half
BLOCK_EXTENTS = (0.12, 0.2, 0.05)  # m: the block's size; its top is 5 cm above the board's
MARGIN = 0.02  # m: targets are kept this far inside a face's edges
SCENARIO = shipped_scenario("paper_n1.yaml")


def perturbed_truth(nominal: System, rng: np.random.Generator) -> System:
    """The nominal system with the laser tilted by ``LASER_DEG`` about a random axis across
    its beam and the (first) mirror mount shifted ``MIRROR_MM`` along its normal."""
    L = nominal.world_T_laser
    axis = np.cross(L[:3, 2], rng.normal(size=3))
    axis *= np.deg2rad(LASER_DEG) / np.linalg.norm(axis)
    L_true = make_T(axis_angle_to_matrix(axis) @ L[:3, :3], L[:3, 3])
    robot = nominal.robots[0]
    M = robot.mirror.flange_T_mirror
    M_true = M.copy()
    M_true[:3, 3] += M[:3, 2] * 1e-3 * MIRROR_MM * rng.choice([-1.0, 1.0])
    return nominal.with_params(L_true, {robot.name: M_true})


def block_item(items: list[Any]) -> Any:
    """The study's block: ``BLOCK_EXTENTS``, standing on the ``BOARD`` box's top face with its
    +x edge at the board's +x edge (world frame, m)."""
    from planner.model.scene import SceneItem

    board = next(i for i in items if i.name == BOARD and i.shape == "box")
    T, ext = board.world_T_object, np.asarray(board.extents)
    size = np.asarray(BLOCK_EXTENTS)
    offset = np.array([ext[0] / 2 - size[0] / 2, 0.0, ext[2] / 2 + size[2] / 2])
    return SceneItem(BLOCK, "box", make_T(T[:3, :3], T[:3, 3] + T[:3, :3] @ offset), size)


def faces(items: list[Any]) -> list[tuple[str, Array, Array, Array]]:
    """The two surfaces targets are drawn on: (name, centre, unit normal, the two in-plane
    half-extent axes 3 x 2, m) of the board's free half and of the block's top."""
    board = next(i for i in items if i.name == BOARD and i.shape == "box")
    block = next(i for i in items if i.name == BLOCK)
    Tb, eb = board.world_T_object, np.asarray(board.extents)
    free_x = eb[0] - BLOCK_EXTENTS[0]  # the board's free part along x, from its -x edge
    centre_b = Tb[:3, 3] + Tb[:3, 2] * eb[2] / 2 + Tb[:3, 0] * (free_x / 2 - eb[0] / 2)
    half_b = Tb[:3, :2] * (np.array([free_x, eb[1]]) / 2 - MARGIN)
    Tk, ek = block.world_T_object, np.asarray(block.extents)
    centre_k = Tk[:3, 3] + Tk[:3, 2] * ek[2] / 2
    half_k = Tk[:3, :2] * (ek[:2] / 2 - MARGIN)
    return [(BOARD, centre_b, Tb[:3, 2], half_b), (BLOCK, centre_k, Tk[:3, 2], half_k)]


class World:
    """The simulated truth: the sim camera on the true system, the board and the block."""

    def __init__(self, scn: Any, truth: System, seed: int) -> None:
        from drivers.camera.sim import SimCamera
        from planner.io.scenario import scene_objects

        items = list(scene_objects(scn))
        items.append(block_item(items))
        self.items = items
        self.truth = truth
        self.camera = SimCamera(truth, items, stride=32, seed=seed)
        self.faces = faces(items)

    def draw(
        self, rng: np.random.Generator, n: int, start: int = 0
    ) -> list[tuple[str, Array, Array]]:
        """``n`` targets (surface name, point m, unit normal; world), on the two surfaces in
        turn from surface ``start``."""
        out = []
        for k in range(n):
            name, centre, normal, half = self.faces[(start + k) % len(self.faces)]
            out.append((name, centre + half @ rng.uniform(-1, 1, 2), normal))
        return out

    def measure(self, q: Array) -> Array | None:
        """The camera-measured spot (camera frame, m) at stacked joints ``q``, or None."""
        for name, qr in self.truth.split_q(q).items():
            self.camera.on_joint_state(name, qr)
        reading = self.camera.spot()
        return None if reading is None else reading.p_camera

    def true_error(self, q: Array, target: Array, normal: Array) -> float:
        """Distance (m) on the target's plane between the true spot at ``q`` and ``target``."""
        from planner.beam.graph import BeamModel

        return float(BeamModel(self.truth).trace(q, target, normal).error)


def trial(seed: int, trial_no: int) -> list[dict[str, Any]]:
    """One trial: a row per (checkpoint, evaluation target) with the true error (mm)."""
    from planner.calibration.online import Calibration, SpotSample, refit
    from planner.ik import BeamIK
    from planner.io.scenario import load_scenario, system_from_scenario

    scn = load_scenario(SCENARIO)
    nominal = system_from_scenario(scn)
    rng = common.trial_rng(seed, trial_no)
    world = World(scn, perturbed_truth(nominal, rng), seed * 1000 + trial_no)
    eval_targets = world.draw(rng, N_EVAL)
    cal, q_prev = Calibration(0, nominal), nominal.home
    samples: list[SpotSample] = []
    ik, tried, accepted, rows = BeamIK(nominal), 0, 0, []
    assert nominal.camera is not None
    misses, drawn = 0, 0
    for checkpoint in CHECKPOINTS:
        while len(samples) < checkpoint and misses < MAX_MISSES:
            surface, target, normal = world.draw(rng, 1, drawn)[0]
            drawn += 1
            sol = ik.solve(target, normal, q_prev)
            p_cam = None if sol.q is None else world.measure(sol.q)
            if sol.q is None or p_cam is None:
                misses += 1
                continue
            q_prev = sol.q
            spot = transform_points(cal.system.camera.world_T_camera, p_cam)  # type: ignore[union-attr]
            samples.append(SpotSample(sol.q, spot, surface=surface))
            res = refit(samples, cal, nominal)
            tried, accepted = tried + 1, accepted + int(res.accepted)
            if res.accepted:
                cal = res.calibration
                ik = BeamIK(cal.system)
        for j, (surface, target, normal) in enumerate(eval_targets):
            sol = ik.solve(target, normal, nominal.home)
            err = np.nan if sol.q is None else 1e3 * world.true_error(sol.q, target, normal)
            rows.append({"trial": trial_no, "samples": checkpoint, "taken": len(samples),
                         "target": j, "surface": surface,
                         "version": cal.version, "error_mm": err,
                         "refits": tried, "accepted": accepted})  # fmt: skip
    return rows


def _by_trial(rows: list[dict[str, Any]]) -> dict[int, Array]:
    """{trial: its rows' errors (mm)}."""
    by: dict[int, list[float]] = {}
    for r in rows:
        by.setdefault(int(r["trial"]), []).append(float(r["error_mm"]))
    return {t: np.array(v) for t, v in by.items()}


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per checkpoint, over the evaluation targets of the trials that reached it (the
    trials that gave up before it are counted apart, in ``gave_up``, and in no figure): the
    mean over the per-trial means of the true error (mm) with its 95 % CI half-width
    (Student t over trials: a trial's targets share its calibration), and the median, p95
    and max over the targets."""
    out = []
    for n in CHECKPOINTS:
        every = [r for r in rows if r["samples"] == n]
        sel = [r for r in every if r["taken"] >= n]
        e = np.array([r["error_mm"] for r in sel], dtype=float)
        ok = e[np.isfinite(e)]
        last = [r for r in sel if r["target"] == 0]
        per_trial = [np.nanmean(v) for v in _by_trial(sel).values() if np.isfinite(v).any()]
        ci = mean_ci(per_trial)
        out.append({
            "samples": n,
            "trials": len(last),
            "gave_up": len({r["trial"] for r in every if r["taken"] < n}),
            "mean_mm": ci.mean,
            "ci95_mm": ci.half_width,
            "median_mm": float(np.median(ok)) if ok.size else np.nan,
            "p95_mm": float(np.percentile(ok, 95)) if ok.size else np.nan,
            "max_mm": float(ok.max()) if ok.size else np.nan,
            "unsolved": int(e.size - ok.size),
            "version_median": float(np.median([r["version"] for r in last])) if last else np.nan,
            "refits_accepted": f"{sum(r['accepted'] for r in last)}/{sum(r['refits'] for r in last)}",
        })  # fmt: skip
    return out


def plot(summary: list[dict[str, Any]], path: Path) -> None:
    """Median and p95 open-loop error vs samples."""
    plt = common.pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    n = [s["samples"] for s in summary]
    ax.plot(n, [s["median_mm"] for s in summary], "o-", label="median")
    ax.plot(n, [s["p95_mm"] for s in summary], "s--", label="p95")
    ax.set_yscale("log")
    ax.set_xlabel("online samples (executed targets with a measured spot)")
    ax.set_ylabel("open-loop error of the next targets (mm)")
    ax.set_title(f"truth off by {LASER_DEG} deg (laser), {MIRROR_MM} mm (mirror)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    common.save_figure(fig, path)


def main(trials: int, seed: int, out: Path, workers: int | None, sched: str | None) -> dict:
    """Open-loop error of the next targets after 0, 5, 10, 20 online calibration samples
    (paper_n1, truth off by 0.4 deg at the laser and 3 mm at the mirror, D435 spot noise)."""
    jobs = [(seed, t) for t in range(trials)]
    rows = [
        r
        for part in common.parallel_map(trial, jobs, workers=workers, scheduler=sched)
        for r in part
    ]
    summary = summarise(rows)
    folder = common.out_dir(out)
    plot(summary, folder / "online.png")
    lines = [
        "# Online calibration refinement",
        "",
        f"{trials} trials, seed {seed}, {N_EVAL} evaluation targets per checkpoint, half on"
        f" the board and half on a block {1e2 * BLOCK_EXTENTS[2]:g} cm above it (samples"
        f" alternate between the two); true geometry off by {LASER_DEG} deg (laser) and"
        f" {MIRROR_MM} mm (mirror mount, along its normal). Errors: true spot vs target on"
        " its surface, open loop, mm; mean over the per-trial means ± `ci95_mm` (95 % CI,"
        " Student t over trials), median / p95 / max over the targets. A trial that gave up"
        " before a checkpoint (too many targets unsolved or unseen) is counted in `gave_up`"
        " and left out of that row's figures.",
        "",
        common.markdown_table(summary),
        "",
    ]
    common.write_report(folder, lines, {"online.csv": rows, "summary.csv": summary},
                        ("open-loop error vs samples", "online.png"))  # fmt: skip
    for s in summary:
        print(f"after {s['samples']:>2} samples: median {s['median_mm']:.3f} mm,"
              f" p95 {s['p95_mm']:.3f} mm (version {s['version_median']:g})")  # fmt: skip
    return {"study": "online", "trials": trials, "checkpoints": summary}


command = common.study_command(main, TRIALS, Path("reports/online"))
