"""The N = 2 relay cell of ``study experiments-n2``: its hidden truth, calibration and targets.

Cell: ``scenarios/n2_relay.yaml`` (laser -> arm0's mirror -> arm1's mirror -> targets behind
a screen; a D435 looking at the targets). World = arm0's base frame, metres, radians.

The truth (:func:`draw_truth`): everything the N = 1 experiments leave unknown
(:class:`~planner.studies.experiments_setup.Unknowns`, drawn by the same
:func:`~planner.studies.experiments_setup.draw_truth`: laser, arm0's mirror mount, camera,
hand-eye board), plus arm1's mirror mount at the same mirror levels and arm1's placement in
the world (arm0's base frame is the world, so only arm1's base is unknown).

Calibration (:func:`calibrate_relay`), all with the product's code on the simulated cell:

1. hand-eye with the board on arm0 (:func:`~planner.studies.experiments_cell.calibrate_handeye_cell`):
   the camera pose in the world;
2. hand-eye with the same board on arm1: the camera pose in arm1's base frame, hence arm1's
   placement ``world_T_base1 = world_T_camera (base1_T_camera)^-1``;
3. :func:`planner.calibration.beam.calibrate_chain`: mirror 1 from spots of the beam leaving
   arm0's mirror on :data:`MIRROR1_HEIGHTS` boards (arm1 out of the beam: laser line and
   mirror 1's plane), then mirror 2 from the whole chain's spots on :data:`MIRROR2_HEIGHTS`
   boards with the laser and mirror 1 held at their calibrated values.

Targets (:func:`experiments`): a 7 x 5 chessboard's corners (point to point) and a sine
curve (closest point) in the scenario's target region, each with the screen in the scene
(the true beam must clear it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np

from planner.data import shipped_scenario
from planner.model.scene import SceneItem
from planner.model.system import System
from planner.model.transforms import Array, inv_T, make_T
from planner.studies import experiments_setup as n1
from planner.studies.experiments_cell import Board, Calibrated

SCENARIO = shipped_scenario("n2_relay.yaml")
ROBOTS = ("arm0", "arm1")
MIRROR1_AIM = np.array([-0.40, 0.0, 0.0])
"""Where arm0 sends the beam to calibrate mirror 1 (world, m): on arm0's side of the
screen, where the camera sees past the screen's end (pixel (211, 182) of 848 x 480, 1.06 m
away; nearer the screen it hides the boards), clear of the laser's own path
(scenarios/n2_relay.yaml layout)."""
MIRROR1_HEIGHTS = (0.0, 0.075, 0.15)
"""Heights (m) of the flat mirror-1 boards on the ray from arm0's mirror to
:data:`MIRROR1_AIM`: three distances, as the N = 1 boards (at 0.15 m the laser's path is
0.34 m from the ray, off a 0.3 m board)."""
MIRROR1_BOARD = 0.3  # m, side: simulate_beam's board (planner.calibration.simulate.BOARD_HALF)
MIRROR2_HEIGHTS = (0.0, 0.05, 0.10)
"""Heights (m) of the flat mirror-2 boards on the home beam toward the target grid centre
(the grid spans z 0.025-0.075 m, scenarios/n2_relay.yaml)."""
MIRROR2_BOARD = 0.2  # m, side: the screen's face is 0.115 m from the grid centre along x


@dataclass(frozen=True)
class RelayUnknowns:
    """The N = 1 unknowns plus arm1's placement (half-widths, rad / m). arm1's base is a
    hand-placed fixture, given the hand-placement level the N = 1 study gives the camera."""

    shared: n1.Unknowns = field(default_factory=n1.Unknowns)
    base_rot: float = n1.Unknowns.camera_rot
    base_pos: float = n1.Unknowns.camera_pos

    def describe(self) -> str:
        """One line: the levels in mm / deg."""
        both = self.shared.describe().replace("mirror mount", "each mirror mount")
        return (
            f"{both}, arm1's base ±{1e3 * self.base_pos:g} mm / ±{np.degrees(self.base_rot):g} deg"
        )


NONE = RelayUnknowns(n1.NONE, 0.0, 0.0)


@lru_cache(maxsize=1)
def nominal_system() -> System:
    """The planner's nominal relay (``scenarios/n2_relay.yaml``)."""
    from planner.io.scenario import load_scenario, system_from_scenario

    return system_from_scenario(load_scenario(SCENARIO))


def scenario_model() -> Any:
    """The relay scenario's parsed model (solver settings, target grid, scene)."""
    from planner.io.scenario import load_scenario

    return load_scenario(SCENARIO)


def draw_truth(nominal: System, u: RelayUnknowns, rng: np.random.Generator,
               effects: n1.Effects | None = None, seed: Any = None) -> n1.Truth:  # fmt: skip
    """A random true relay about ``nominal`` (see the module docstring). With ``effects``
    (:class:`~planner.studies.experiments_setup.Effects`), each true arm also has DH deltas
    at ``effects.robot``'s spread and the true camera its depth errors, each from a stream
    of its own (``[*seed, 1]``, ``[*seed, 2]``, as the N = 1 trials draw them), so the other
    draws stay those of the kind simulation."""
    truth = n1.draw_truth(nominal, u.shared, rng)
    arm1 = nominal.robots[1]
    mount = n1.perturb(arm1.mirror.flange_T_mirror, rng, u.shared.mirror_rot, u.shared.mirror_pos)
    base = n1.perturb(arm1.world_T_base, rng, u.base_rot, u.base_pos)
    system = truth.system.with_params(
        flange_T_mirror={arm1.name: mount}, world_T_base={arm1.name: base}
    )
    if effects is None:
        return replace(truth, system=system)
    seq = list(seed or [])
    spread = effects.robot_spread
    if spread is not None:
        from planner.model.kinematic_error import true_robot

        robot_rng = np.random.default_rng(np.random.SeedSequence([*seq, 1]))
        arms = [true_robot(r, spread, robot_rng) for r in system.robots]
        system = replace(system, robots=tuple(arms))
    camera_rng = np.random.default_rng(np.random.SeedSequence([*seq, 2]))
    return replace(truth, system=system, depth_errors=effects.depth_errors(nominal, camera_rng))


# --- scene ----------------------------------------------------------------------------------
@lru_cache(maxsize=1)
def screen() -> SceneItem:
    """The scenario's screen (the only scene object of ``scenarios/n2_relay.yaml``)."""
    from planner.io.scenario import scene_objects

    (item,) = scene_objects(scenario_model())
    return item


def grid_center() -> Array:
    """Centre of the scenario's target grid (world, m)."""
    return np.asarray(scenario_model().model.targets.grid.center, dtype=float)


def _flat_board(name: str, centre: Array, side: float) -> SceneItem:
    return n1.board_box(name, make_T(p=centre), (side, side))


def _on_ray(origin: Array, through: Array, z: float) -> Array:
    """The point at height ``z`` of the ray from ``origin`` through ``through``."""
    d = through - origin
    return origin + d * (z - origin[2]) / d[2]


def calibration_boards(nominal: System, robot: str) -> list[Board]:
    """The beam calibration boards of ``robot``'s mirror (aim point, board): flat, on the
    ray from its mirror at home through :data:`MIRROR1_AIM` (arm0) or the grid centre."""
    first = robot == ROBOTS[0]
    i = 0 if first else 1
    through = MIRROR1_AIM if first else grid_center()
    heights, side = (MIRROR1_HEIGHTS, MIRROR1_BOARD) if first else (MIRROR2_HEIGHTS, MIRROR2_BOARD)
    centre = home_mirror(nominal, i)[:3, 3]
    aims = [_on_ray(centre, through, z) for z in heights]
    return [(a, _flat_board(f"{robot}_board_z{a[2]:+.3f}", a, side)) for a in aims]


# --- calibration ----------------------------------------------------------------------------
@dataclass(frozen=True)
class RelayCalibrated(Calibrated):
    """The calibrated relay, with each stage's result (hand-eyes, beam results per mirror)."""

    handeye: tuple[Any, ...] = ()
    beams: tuple[Any, ...] = ()


def calibrate_relay(nominal: System, truth: n1.Truth, rng: np.random.Generator) -> RelayCalibrated:
    """Hand-eye on both arms, then the mirrors in beam order (module docstring)."""
    from planner.calibration.beam import calibrate_chain
    from planner.studies.experiments_cell import calibrate_handeye_cell, collect_beam_cell

    assert nominal.camera is not None
    he0 = calibrate_handeye_cell(nominal, truth, rng, ROBOTS[0])
    he1 = calibrate_handeye_cell(nominal, truth, rng, ROBOTS[1])
    w_T_cam = he0.camera_pose
    base1_T_cam = inv_T(nominal.robots[1].world_T_base) @ he1.camera_pose
    system = nominal.with_params(world_T_base={ROBOTS[1]: w_T_cam @ inv_T(base1_T_cam)})
    system = replace(system, camera=replace(nominal.camera, world_T_camera=w_T_cam))

    def collect(plan_system: System, robot: str) -> Any:
        boards = calibration_boards(plan_system, robot)
        return collect_beam_cell(plan_system, truth, w_T_cam, rng, robot, boards, (screen(),))

    system, beams = calibrate_chain(system, collect)
    return RelayCalibrated(
        system,
        np.concatenate([he0.point_residuals, he1.point_residuals]),
        np.concatenate([b.residuals for b in beams]),
        sum(len(b.residuals) for b in beams),
        (he0, he1),
        tuple(beams),
    )


# --- targets --------------------------------------------------------------------------------
def chessboard() -> n1.Experiment:
    """7 x 5 corners (25 mm, the N = 1 chessboard) on a flat board at the grid centre, its
    7-corner side along y (the grid's long side)."""
    T = make_T(p=grid_center())
    gx, gy = np.meshgrid(np.arange(-2, 3) * 0.025, np.arange(-3, 4) * 0.025)
    pts, n = n1.on_plane(T, np.column_stack([gx.ravel(), gy.ravel()]))
    board = n1.board_box("chessboard", T, (MIRROR2_BOARD, MIRROR2_BOARD))
    return n1.Experiment("chessboard", (board, screen()), pts, n, n1.POINT)


def curve() -> n1.Experiment:
    """40 samples of a sine curve along y (120 mm, amplitude 20 mm, period 60 mm: the N = 1
    curve's shape scaled to the grid's 100 mm side) on a board 50 mm below the grid centre."""
    T = make_T(p=grid_center() - np.array([0.0, 0.0, 0.05]))
    s = np.linspace(-0.06, 0.06, 40)
    pts, n = n1.on_plane(T, np.column_stack([0.02 * np.sin(2 * np.pi * s / 0.06), s]))
    board = n1.board_box("curve_board", T, (MIRROR2_BOARD, MIRROR2_BOARD))
    return n1.Experiment("curve", (board, screen()), pts, n, n1.CLOSEST, (np.arange(len(s)),))


def experiments() -> list[n1.Experiment]:
    """The relay's experiment runs of one trial."""
    return [chessboard(), curve()]


# --- calibration errors ---------------------------------------------------------------------
def _angle_deg(a: Array, b: Array) -> float:
    """Angle (deg) between two unit vectors, accurate near zero (atan2)."""
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), float(a @ b))))


def home_mirror(system: System, i: int) -> Array:
    """``world_T_mirror`` of robot ``i``'s mirror at its home joints."""
    r = system.robots[i]
    return r.world_T_base @ r.kinematics.fk(r.home) @ r.mirror.flange_T_mirror


def calibration_errors(calibrated: System, truth: System) -> dict[str, float]:
    """What the beam sees of each calibrated part against the truth (deg, mm; world): the
    laser's direction and the distance of its true origin from the calibrated line; each
    mirror's plane at home (the normal's angle; the true centre's distance from the
    calibrated plane); arm1's base origin and the camera's origin. The unobservable (gauge)
    directions, which move no beam, are left out."""
    Lc, Lt = calibrated.world_T_laser, truth.world_T_laser
    d = Lc[:3, 2]
    off = Lt[:3, 3] - Lc[:3, 3]
    out = {"laser_deg": _angle_deg(d, Lt[:3, 2]),
           "laser_mm": 1e3 * float(np.linalg.norm(off - d * float(d @ off)))}  # fmt: skip
    for i in range(calibrated.n_robots):
        Mc, Mt = home_mirror(calibrated, i), home_mirror(truth, i)
        out[f"mirror{i + 1}_deg"] = _angle_deg(Mc[:3, 2], Mt[:3, 2])
        out[f"mirror{i + 1}_mm"] = 1e3 * abs(float(Mc[:3, 2] @ (Mt[:3, 3] - Mc[:3, 3])))
    bc, bt = calibrated.robots[-1].world_T_base, truth.robots[-1].world_T_base
    out["arm1_base_mm"] = 1e3 * float(np.linalg.norm(bc[:3, 3] - bt[:3, 3]))
    assert calibrated.camera is not None and truth.camera is not None
    cc, ct = calibrated.camera.world_T_camera, truth.camera.world_T_camera
    out["camera_mm"] = 1e3 * float(np.linalg.norm(cc[:3, 3] - ct[:3, 3]))
    return out
