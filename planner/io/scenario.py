"""Scenario files -> the planner's model: :class:`System`, :class:`Targets`, scene objects.

Main flow: :func:`load_scenario` reads the YAML, applies its ``include:`` files, validates it
(every error names file, line and key path) and keeps the source; then
:func:`system_from_scenario` and :func:`targets_from_scenario` resolve defaults into frozen
dataclasses of numpy arrays. All outputs are in the world frame, in metres and radians.
"""

from __future__ import annotations

import copy
import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from planner.errors import InputError, ScenarioError
from planner.io.plausibility import emit, scenario_warnings
from planner.io.strokes import mark_path
from planner.model import robots
from planner.model.motion import motion_from_schema
from planner.model.scene import SceneItem, SceneModel
from planner.model.settings import TrajectorySettings
from planner.model.system import (
    DEFAULT_HOME,
    Camera,
    Intrinsics,
    Limits,
    Mirror,
    Robot,
    System,
    Targets,
)
from planner.model.transforms import Array, transform_points
from schemas.calibration import CalibrationFile, report_spot_uncertainty
from schemas.common import FieldError
from schemas.located import Loc, Origins, merge_partial, rebase_origins, validate, where
from schemas.scenario import Camera as CameraModel
from schemas.scenario import Robot as RobotModel
from schemas.scenario import Scenario, check_joint_lengths
from schemas.scenario import System as SystemModel
from schemas.yamlio import read_yaml

LIMIT_KEYS = ("lower", "upper", "velocity", "acceleration", "jerk")


@dataclass(frozen=True)
class LoadedScenario:
    """A validated scenario with its includes applied, and where it came from.

    ``source`` is the file name as shown in messages; ``base_dir`` is the directory that
    relative ``urdf``/``mesh`` paths resolve against; ``origins`` maps key paths to
    (file, line). ``truth_system`` is ``system`` with ``truth.system`` merged over it.
    ``warnings`` are ``file:line key.path: reason`` lines for valid but suspicious values.
    """

    model: Scenario
    source: str
    base_dir: Path
    origins: Origins = field(default_factory=dict)
    truth_system: SystemModel | None = None
    includes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.model.name or Path(self.source).stem

    def where(self, loc: Loc) -> str:
        """``file:line key.path`` of a key path of the (merged) scenario."""
        return where(self.origins, loc, self.source)

    def camera_pose_file(self) -> str | None:
        """The file that gave the camera's pose (``world_T_camera`` or ``flange_T_camera``):
        an ``include:`` file once a hand-eye result is included, else the scenario itself;
        None without a camera."""
        for key in ("world_T_camera", "flange_T_camera"):
            origin = self.origins.get(("system", "camera", key))
            if origin is not None:
                return origin[0]
        return None

    @property
    def camera_is_nominal(self) -> bool:
        """True when the camera pose comes from the scenario, not from an included file."""
        shown = self.camera_pose_file()
        return shown is not None and shown == self.source

    def resolve_path(self, relative: str) -> Path:
        """A path from the scenario (``urdf``, ``mesh``) made absolute."""
        return (self.base_dir / Path(relative).expanduser()).resolve()


# --- loading ------------------------------------------------------------------------------
def load_scenario(path: str | Path, extra_includes: tuple[str | Path, ...] = ()) -> LoadedScenario:
    """Read, merge ``include:`` files into, and validate a scenario file.

    Args:
        path: the scenario YAML; relative ``include``, ``urdf`` and ``mesh`` paths resolve
            against its folder.
        extra_includes: calibration files applied after the scenario's own ``include:``
            (the planner node's online calibration).

    Returns:
        The :class:`LoadedScenario` (validated model, origins of every key, warnings).
        Raises :class:`ScenarioError` with ``file:line key.path`` for any problem, including
        a missing URDF or mesh file.
    """
    shown = str(path)
    data, origins = read_yaml(path, ScenarioError)
    if extra_includes and isinstance(data, dict):
        own = data.get("include") or []
        data["include"] = [*(own if isinstance(own, list) else [own]), *map(str, extra_includes)]
    return _build(data, origins, shown, Path(path).parent, check_files=True)


def scenario_from_dict(
    data: dict[str, Any], *, source: str = "<scenario>", base_dir: str | Path = "."
) -> LoadedScenario:
    """A scenario from an in-memory mapping (e.g. plan.json's resolved ``scenario``)."""
    return _build(copy.deepcopy(data), {(): (source, 0)}, source, Path(base_dir), check_files=False)


def _build(
    data: Any, origins: Origins, shown: str, base_dir: Path, *, check_files: bool
) -> LoadedScenario:
    if not isinstance(data, dict):
        reason = "file is empty" if data is None else "expected a mapping of scenario keys"
        raise ScenarioError(reason, where(origins, ()))
    includes = data.get("include") or []
    if not isinstance(includes, list) or not all(isinstance(s, str) for s in includes):
        validate(Scenario, data, origins=origins, source=shown, error_cls=ScenarioError)
        includes = []
    for j, name in enumerate(includes):
        _apply_include(data, origins, name, shown, base_dir, where(origins, ("include", j)))
    model = validate(Scenario, data, origins=origins, source=shown, error_cls=ScenarioError)
    truth = None
    if model.truth is not None:  # truth.system over system, errors located in either
        loc = ("truth", "system")
        merged, truth_origins = (
            copy.deepcopy(data["system"]),
            rebase_origins(origins, ("system",), loc),
        )
        kw: dict[str, Any] = {"base_loc": loc, "over_loc": loc, "error_cls": ScenarioError}
        merge_partial(
            merged, data["truth"]["system"], origins=truth_origins, over_origins=origins, **kw
        )
        truth = validate(
            SystemModel, merged, origins=truth_origins, prefix=loc, error_cls=ScenarioError
        )
    scn = LoadedScenario(model, shown, base_dir, origins, truth, tuple(includes))
    if check_files:
        _check_files(scn)
        lines = [f"{scn.where(loc)}: {reason}" for loc, reason in scenario_warnings(model)]
        scn = dataclasses.replace(scn, warnings=tuple(lines))
        emit(lines)
    return scn


def _apply_include(
    data: dict[str, Any], origins: Origins, name: str, shown: str, base_dir: Path, place: str
) -> None:
    path = base_dir / name
    inc_shown = os.path.normpath(os.path.join(os.path.dirname(shown), name))
    if not path.is_file():
        raise ScenarioError(f"include file not found: {inc_shown}", place)
    inc, inc_origins = read_yaml(path, ScenarioError, shown=inc_shown)
    validate(CalibrationFile, inc, origins=inc_origins, source=inc_shown, error_cls=ScenarioError)
    u = report_spot_uncertainty(inc.get("report")) if isinstance(inc, dict) else 0.0
    safety = data.setdefault("safety", {}) if u > 0 else None
    if isinstance(safety, dict) and u > float(safety.get("spot_uncertainty") or 0.0):
        safety["spot_uncertainty"] = (
            u  # the safety margin grows by 3 x it (docs/conventions.md section 4)
        )
        origins[("safety", "spot_uncertainty")] = (inc_shown, 0)
    if isinstance(inc, dict) and inc.get("system"):
        over = {"system": inc["system"]}
        merge_partial(
            data, over, origins=origins, over_origins=inc_origins, error_cls=ScenarioError
        )


def _check_files(scn: LoadedScenario) -> None:
    files: list[tuple[Loc, str | None]] = [
        (("scene", i, "mesh"), o.mesh) for i, o in enumerate(scn.model.scene)
    ]
    files += [(("keep_out", i, "mesh"), o.mesh) for i, o in enumerate(scn.model.keep_out)]
    for root, system in ((("system",), scn.model.system), (("truth", "system"), scn.truth_system)):
        robots = system.robots if system is not None else []
        files += [((*root, "robots", i, "urdf"), r.urdf) for i, r in enumerate(robots)]
    for loc, name in files:
        if name is not None and not scn.resolve_path(name).is_file():
            raise ScenarioError(f"file not found: {scn.resolve_path(name)}", scn.where(loc))


# --- system -------------------------------------------------------------------------------
def robot_model(model: RobotModel, scn: LoadedScenario, loc: Loc) -> robots.RobotModel:
    """The (cached, shared) robot model of a robot entry: its ``model`` by name (default
    ``ur5e``) from :mod:`planner.model.robots`, or its ``urdf``."""
    key = "model" if model.urdf is None else "urdf"
    try:
        if model.urdf is not None:
            return robots.robot_model(scn.resolve_path(model.urdf))
        return robots.robot_model(model.model or robots.DEFAULT_MODEL)
    except InputError as exc:
        raise ScenarioError(exc.reason, scn.where((*loc, key))) from None


def system_from_scenario(scn: LoadedScenario, *, truth: bool = False) -> System:
    """The resolved :class:`System` (defaults filled in, poses as 4x4 arrays, world frame, m).

    Args:
        scn: a scenario from :func:`load_scenario`.
        truth: use ``truth.system`` merged over ``system`` (the geometry simulated drivers
            use); without a ``truth`` section it is the nominal system.

    Returns:
        The :class:`System`: laser pose, robots (kinematics from
        :func:`planner.model.robots.robot_model`, limits, home, mirror), camera.
    """
    use_truth = truth and scn.truth_system is not None
    model = scn.truth_system if use_truth and scn.truth_system else scn.model.system
    root: Loc = ("truth", "system") if use_truth else ("system",)
    robots = tuple(_robot(r, scn, (*root, "robots", i)) for i, r in enumerate(model.robots))
    camera = None if model.camera is None else _camera(model.camera, robots)
    return System(model.laser.world_T_laser.matrix(), robots, camera)


def _camera(cam: CameraModel, robots: tuple[Robot, ...]) -> Camera:
    """A fixed camera, or one on a robot's flange posed at that robot's home joints."""
    k = cam.intrinsics
    intrinsics = Intrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    if cam.world_T_camera is not None:
        return Camera(cam.world_T_camera.matrix(), intrinsics)
    assert cam.robot is not None and cam.flange_T_camera is not None  # schema: one mount
    r = next(r for r in robots if r.name == cam.robot)
    flange_T_camera = cam.flange_T_camera.matrix()
    world_T_camera = r.world_T_base @ r.kinematics.fk(r.home) @ flange_T_camera
    return Camera(world_T_camera, intrinsics, r.name, flange_T_camera)


def _robot(r: RobotModel, scn: LoadedScenario, loc: Loc) -> Robot:
    arm = robot_model(r, scn, loc)
    kin, nq = arm.kinematics, arm.nq
    try:
        check_joint_lengths(r.home, r.limits, nq)
    except FieldError as exc:
        raise ScenarioError(exc.reason, scn.where((*loc, *exc.loc))) from None
    default = arm.limits
    given = r.limits.model_dump() if r.limits is not None else {}
    values = {k: np.asarray(given.get(k) or getattr(default, k), dtype=float) for k in LIMIT_KEYS}
    limits = Limits(**values)
    for j in np.flatnonzero(limits.lower >= limits.upper):
        raise ScenarioError(
            f"lower limit {limits.lower[j]:g} is not below upper {limits.upper[j]:g}",
            scn.where((*loc, "limits")),
        )
    home = np.asarray(r.home if r.home is not None else _default_home(nq), dtype=float)
    for j in np.flatnonzero((home < limits.lower) | (home > limits.upper)):
        raise ScenarioError(
            f"{home[j]:g} rad is outside the joint limits [{limits.lower[j]:g}, {limits.upper[j]:g}]",
            scn.where((*loc, "home", int(j))),
        )
    mirror = Mirror(
        flange_T_mirror=r.mirror.flange_T_mirror.matrix(),
        size=(r.mirror.size[0], r.mirror.size[1]),
        roi_margin=r.mirror.roi_margin,
    )
    return Robot(r.name, kin, r.world_T_base.matrix(), mirror, home, limits)


def _default_home(nq: int) -> Array:
    return np.array(DEFAULT_HOME) if nq == len(DEFAULT_HOME) else np.zeros(nq)


# --- targets ------------------------------------------------------------------------------
def targets_from_scenario(scn: LoadedScenario, system: System) -> Targets:
    """The scenario's targets in the world frame (grid expanded, path resampled).

    Args:
        scn: a scenario from :func:`load_scenario`.
        system: its :func:`system_from_scenario` (for ``frame: camera`` targets, mapped with
            the camera pose; a camera on a flange at its robot's home joints).

    Returns:
        :class:`Targets`: ``points`` (K, 3) m, world frame; ``normals`` (K, 3) or None when
        the scenario gives none; ``meta`` with ``order`` and ``frame`` (plus ``n`` for a
        grid, ``spacing`` and ``vertices`` for a path).
    """
    spec = scn.model.targets
    world_T_frame = np.eye(4)
    if spec.frame == "camera":
        if system.camera is None:
            raise ScenarioError(
                "is camera but the system has no camera", scn.where(("targets", "frame"))
            )
        world_T_frame = system.world_T_camera()
    meta: dict[str, object] = {"order": spec.order, "frame": spec.frame}
    closed = False
    normals: Array | None = None
    if spec.points is not None:
        points = np.asarray(spec.points, dtype=float)
        normals = None if spec.normals is None else np.asarray(spec.normals, dtype=float)
    elif spec.grid is not None:
        points = grid_points(spec.grid.center, spec.grid.size, spec.grid.n)
        meta["n"] = tuple(spec.grid.n)
    else:
        assert spec.path is not None

        closed, path = spec.path.closed, spec.path
        try:
            marked = mark_path(path.points, path.spacing, normals=path.normals, closed=closed,
                               corner_deg=path.corner_deg, smooth=path.smooth,
                               tolerance=scn.model.trajectory.path_tolerance)  # fmt: skip
        except InputError as exc:  # exc.where: the path's field (points, normals)
            raise ScenarioError(exc.reason, scn.where(("targets", "path", exc.where))) from None
        points, normals = marked.points, marked.normals
        meta |= {"spacing": path.spacing, "vertices": len(path.points)} | marked.meta()
    points = transform_points(world_T_frame, points)
    if normals is not None:
        normals = normals @ world_T_frame[:3, :3].T
    return Targets(points=points, normals=normals, kind=spec.kind, closed=closed, meta=meta)


def grid_points(center: Any, size: Any, n: Any) -> Array:
    """``n[i]`` points per axis from ``center - size/2`` to ``center + size/2`` inclusive;
    ``n[i] = 1`` gives the centre. Returns ``(prod(n), 3)``, x slowest."""
    c, s = np.asarray(center, dtype=float), np.asarray(size, dtype=float)
    axes = [
        np.array([c[i]]) if n[i] == 1 else np.linspace(c[i] - s[i] / 2, c[i] + s[i] / 2, n[i])
        for i in range(3)
    ]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


# --- scene and resolved dict --------------------------------------------------------------
def scene_objects(scn: LoadedScenario) -> list[SceneItem]:
    """The scene list with world matrices and absolute mesh paths."""
    items = []
    for obj in scn.model.scene:
        T = obj.world_T_object.matrix()
        mv = None if obj.motion is None else motion_from_schema(obj.motion)
        if obj.box is not None:
            extents = np.asarray(obj.box, dtype=float)
            items.append(SceneItem(obj.name, "box", T, extents=extents, motion=mv))
        elif obj.sphere is not None:
            items.append(SceneItem(obj.name, "sphere", T, radius=obj.sphere, motion=mv))
        elif obj.cylinder is not None:
            r, h = obj.cylinder
            items.append(SceneItem(obj.name, "cylinder", T, radius=r, height=h, motion=mv))
        elif obj.mesh is not None:
            path, scale = scn.resolve_path(obj.mesh), obj.scale or 1.0
            items.append(SceneItem(obj.name, "mesh", T, mesh_path=path, scale=scale, motion=mv))
    return items


def trajectory_settings(scn: LoadedScenario) -> TrajectorySettings:
    """The scenario's ``trajectory`` section as typed settings (defaults filled in)."""
    return TrajectorySettings.from_mapping(scn.model.trajectory.model_dump())


def scene_model(scn: LoadedScenario) -> SceneModel:
    """The raycasting model of a loaded scenario's ``scene:`` objects (world frame, m)."""
    return SceneModel(scene_objects(scn))


def keep_out_objects(scn: LoadedScenario) -> list[SceneItem]:
    """The ``keep_out`` volumes (sphere, box or mesh) with world matrices and absolute mesh
    paths."""
    items = []
    for obj in scn.model.keep_out:
        T = obj.world_T_object.matrix()
        if obj.box is not None:
            items.append(SceneItem(obj.name, "box", T, extents=np.asarray(obj.box, dtype=float)))
        elif obj.sphere is not None:
            items.append(SceneItem(obj.name, "sphere", T, radius=obj.sphere))
        elif obj.mesh is not None:
            path, scale = scn.resolve_path(obj.mesh), obj.scale or 1.0
            items.append(SceneItem(obj.name, "mesh", T, mesh_path=path, scale=scale))
    return items
