"""An in-process simulated world for closed-loop work: a miscalibrated system and its camera.

The shipped ``paper_n1`` scenario (N = 1 UR5e, laser, D435 at ~0.85 m from the board) is the
planner's calibrated *model*. Its ``truth:`` - what the simulated camera traces - tilts the
laser by ``laser_deg`` about its x axis and moves the mirror ``mount_m`` further out along
the flange's z axis (defaults 0.4 deg and 3 mm: open-loop spots then land ~5.5 mm from
targets on the board). The camera is :class:`drivers.camera.sim.SimCamera` on the truth
(D435 depth and centroid noise, the spot only where the true beam lands and the camera sees
it); measurements are mapped to the world with the *model's* camera pose, as the planner node
does. No processes, no bus.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml

from planner.data import shipped_scenario
from planner.io.scenario import LoadedScenario, scenario_from_dict, scene_objects
from planner.io.scenario import system_from_scenario as resolve
from planner.model.transforms import Array
from planner.servo.measure import SpotFrame, SpotMeasurement, average_frames

LASER_DEG = 0.4  # truth laser tilt about its x axis, deg
MOUNT_M = 0.003  # truth mirror mount offset along the flange z axis, m
BOARD_Z = -0.06  # m: the board's top face in paper_n1 (world)
UP = np.array([0.0, 0.0, 1.0])


def perturbed_scenario(
    laser_deg: float = LASER_DEG, mount_m: float = MOUNT_M, camera_error: Array | None = None
) -> LoadedScenario:
    """``paper_n1`` with a ``truth:`` laser tilted ``laser_deg`` (deg) about x and mirror
    mount moved ``mount_m`` (m) along the flange z axis; with ``camera_error`` (4 x 4, in the
    calibrated camera's frame) the true camera is at ``world_T_camera @ camera_error``."""
    from planner.io.scenario import load_scenario

    path = shipped_scenario("paper_n1.yaml")
    data: dict[str, Any] = yaml.safe_load(path.read_text())
    laser = dict(data["system"]["laser"]["world_T_laser"])
    laser["rpy_deg"] = [laser["rpy_deg"][0] + laser_deg, *laser["rpy_deg"][1:]]
    robot = data["system"]["robots"][0]
    mount = dict(robot["mirror"]["flange_T_mirror"])
    mount["xyz"] = [mount["xyz"][0], mount["xyz"][1], mount["xyz"][2] + mount_m]
    data["truth"] = {"system": {"laser": {"world_T_laser": laser},
                                "robots": [{"name": robot["name"],
                                            "mirror": {"flange_T_mirror": mount}}]}}  # fmt: skip
    if camera_error is not None:
        model = resolve(load_scenario(path))
        assert model.camera is not None
        true_pose = model.camera.world_T_camera @ np.asarray(camera_error, dtype=float)
        data["truth"]["system"]["camera"] = {"world_T_camera": {"matrix": true_pose.tolist()}}
    return scenario_from_dict(data, source=f"{path} (perturbed truth)", base_dir=path.parent)


def camera_error(mm: float, deg: float, seed: int) -> Array:
    """A camera pose error (4 x 4, camera frame): ``mm`` millimetres along, and ``deg``
    degrees about (through the camera centre), unit directions drawn with ``seed``."""
    from planner.model.transforms import axis_angle_to_matrix, make_T

    rng = np.random.default_rng(seed)
    d, axis = rng.normal(size=3), rng.normal(size=3)
    d, axis = d / np.linalg.norm(d), axis / np.linalg.norm(axis)
    return make_T(axis_angle_to_matrix(np.deg2rad(deg) * axis), 1e-3 * mm * d)


def board_targets(k: int, seed: int) -> Array:
    """``k`` random targets (k x 3, world, m) on the board's top face under the work cube."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-0.56, -0.59], [-0.44, -0.47], (k, 2))
    return np.column_stack([xy, np.full(k, BOARD_Z)])


class SimWorld:
    """The model, the truth and the simulated camera of one scenario with a ``truth:``.

    ``measure(q, frames)`` puts the (simulated) arms at stacked ``q`` (rad), grabs ``frames``
    camera frames and averages them (:func:`planner.servo.measure.average_frames`) through
    the model's camera pose; ``frames_grabbed`` counts every frame."""

    def __init__(
        self, scn: LoadedScenario | None = None, *, seed: int = 0, stride: int = 8
    ) -> None:
        from drivers.camera.sim import SimCamera

        self.scenario = scn or perturbed_scenario()
        self.model = resolve(self.scenario)
        self.truth = resolve(self.scenario, truth=True)
        if self.model.camera is None:
            raise ValueError("the servo world needs a camera in the scenario")
        self.camera = SimCamera(self.truth, scene_objects(self.scenario), stride=stride, seed=seed)
        self.world_T_camera = self.model.camera.world_T_camera
        self.frames_grabbed = 0

    def frames(self, q: Array, n: int) -> list[SpotFrame]:
        """``n`` camera frames with the arms at stacked ``q`` (rad)."""
        for name, qi in self.model.split_q(np.asarray(q, dtype=float)).items():
            self.camera.on_joint_state(name, qi)
        out = []
        for _ in range(n):
            r = self.camera.spot()
            out.append(SpotFrame(None) if r is None else SpotFrame(r.p_camera, r.confidence))
        self.frames_grabbed += n
        return out

    def measure(self, q: Array, frames: int) -> SpotMeasurement | None:
        """The averaged spot (world, m) at stacked ``q`` over ``frames`` frames, or None."""
        return average_frames(self.frames(q, frames), self.world_T_camera)

    def true_spot(self, q: Array) -> Array | None:
        """The noiseless true spot (world, m) at stacked ``q``, or None when not seen."""
        for name, qi in self.model.split_q(np.asarray(q, dtype=float)).items():
            self.camera.on_joint_state(name, qi)
        hit = self.camera.true_spot_world()
        return None if hit is None else hit[0]
