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
from planner.model.kinematics import RobotKinematics
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
from schemas.calibration import CalibrationFile
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


@dataclass(frozen=True)
class SceneItem:
    """A scene object in the world. ``shape`` is box | mesh | sphere | cylinder.

    ``extents``: box full size (m); ``radius``/``height``: sphere or cylinder (along the
    object's z, centred); ``mesh_path`` (absolute) scaled by ``scale`` into metres.
    """

    name: str
    shape: str
    world_T_object: Array
    extents: Array | None = None
    radius: float | None = None
    height: float | None = None
    mesh_path: Path | None = None
    scale: float = 1.0


# --- loading ------------------------------------------------------------------------------
def load_scenario(path: str | Path) -> LoadedScenario:
    """Read, merge ``include:`` files into, and validate a scenario file.

    Raises :class:`ScenarioError` with ``file:line key.path`` for any problem, including a
    missing URDF or mesh file.
    """
    shown = str(path)
    data, origins = read_yaml(path, ScenarioError)
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
_KINEMATICS: dict[str, RobotKinematics] = {}


def robot_kinematics(model: RobotModel, scn: LoadedScenario, loc: Loc) -> RobotKinematics:
    """The (cached, shared) kinematics of a robot entry: nominal UR5e or its URDF."""
    key = "ur5e" if model.urdf is None else str(scn.resolve_path(model.urdf))
    if key not in _KINEMATICS:
        try:
            kin = RobotKinematics.ur5e() if model.urdf is None else RobotKinematics.from_urdf(key)
        except InputError as exc:
            raise ScenarioError(exc.reason, scn.where((*loc, "urdf"))) from None
        _KINEMATICS[key] = kin
    return _KINEMATICS[key]


def system_from_scenario(scn: LoadedScenario, *, truth: bool = False) -> System:
    """The resolved :class:`System` (defaults filled in, poses as 4x4 arrays).

    ``truth=True`` uses ``truth.system`` merged over ``system`` (the geometry simulated
    drivers use); without a ``truth`` section it is the nominal system.
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
    kin = robot_kinematics(r, scn, loc)
    nq = kin.nq
    try:
        check_joint_lengths(r.home, r.limits, nq)
    except FieldError as exc:
        raise ScenarioError(exc.reason, scn.where((*loc, *exc.loc))) from None
    default = kin.default_limits()
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

    ``frame: camera`` coordinates are mapped with the camera pose (for a camera on a
    flange: at its robot's home joints).
    ``normals`` is None when the scenario gives none. ``meta`` holds ``order`` and ``frame``
    (plus ``n`` for a grid, ``spacing`` and ``vertices`` for a path).
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
        closed = spec.path.closed
        try:
            points, normals = resample_path(
                spec.path.points,
                spacing=spec.path.spacing,
                normals=spec.path.normals,
                closed=closed,
            )
        except ValueError as exc:
            raise ScenarioError(str(exc), scn.where(("targets", "path"))) from None
        meta |= {"spacing": spec.path.spacing, "vertices": len(spec.path.points)}
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


def resample_path(
    points: Any, *, spacing: float, normals: Any = None, closed: bool = False
) -> tuple[Array, Array | None]:
    """Samples along a polyline, consecutive ones exactly ``spacing`` (m) apart.

    Walks from the first vertex, each next sample being the first polyline point at
    straight-line distance ``spacing`` from the previous one; the last vertex (the first
    one again when ``closed``) ends the path, closer than ``spacing``. Per-vertex
    ``normals`` are interpolated linearly along each segment and renormalised.
    Raises ``ValueError`` for a zero-length path or opposite normals on one segment.
    """
    V = np.asarray(points, dtype=float)
    N = None if normals is None else np.asarray(normals, dtype=float)
    N = None if N is None else N / np.linalg.norm(N, axis=1, keepdims=True)
    if closed:
        V = np.vstack([V, V[:1]])
        N = None if N is None else np.vstack([N, N[:1]])
    if float(np.sum(np.linalg.norm(np.diff(V, axis=0), axis=1))) < 1e-12:
        raise ValueError("path has zero length")
    if N is not None:
        for v in np.flatnonzero(np.einsum("ij,ij->i", N[:-1], N[1:]) < -1 + 1e-9):
            raise ValueError(
                f"normals of vertices {v} and {v + 1} are opposite; cannot interpolate"
            )
    samples: list[tuple[int, float]] = [(0, 0.0)]
    c, k = V[0], 0
    while True:
        for j in range(k, len(V) - 1):
            A, B = V[j], V[j + 1]
            if np.linalg.norm(B - c) < spacing:
                continue
            d, f = B - A, A - c
            a, b, cc = d @ d, 2 * (f @ d), f @ f - spacing**2
            u = float((-b + np.sqrt(max(b * b - 4 * a * cc, 0.0))) / (2 * a))
            samples.append((j, min(max(u, 0.0), 1.0)))
            c, k = A + u * d, j
            break
        else:
            break
    end = (len(V) - 2, 1.0)
    if np.linalg.norm(V[-1] - c) > 1e-9:
        samples.append(end)
    elif len(samples) > 1:
        samples[-1] = end
    seg = np.array([s[0] for s in samples])
    u_arr = np.array([s[1] for s in samples])[:, None]
    P = (1 - u_arr) * V[seg] + u_arr * V[seg + 1]
    if N is None:
        return P, None
    Ns = (1 - u_arr) * N[seg] + u_arr * N[seg + 1]
    return P, Ns / np.linalg.norm(Ns, axis=1, keepdims=True)


# --- scene and resolved dict --------------------------------------------------------------
def scene_objects(scn: LoadedScenario) -> list[SceneItem]:
    """The scene list with world matrices and absolute mesh paths."""
    items = []
    for obj in scn.model.scene:
        T = obj.world_T_object.matrix()
        if obj.box is not None:
            items.append(SceneItem(obj.name, "box", T, extents=np.asarray(obj.box, dtype=float)))
        elif obj.sphere is not None:
            items.append(SceneItem(obj.name, "sphere", T, radius=obj.sphere))
        elif obj.cylinder is not None:
            r, h = obj.cylinder
            items.append(SceneItem(obj.name, "cylinder", T, radius=r, height=h))
        elif obj.mesh is not None:
            path, scale = scn.resolve_path(obj.mesh), obj.scale or 1.0
            items.append(SceneItem(obj.name, "mesh", T, mesh_path=path, scale=scale))
    return items


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


def _item_dict(item: SceneItem) -> dict[str, Any]:
    """A scene object or keep-out volume as resolved YAML (pose as a matrix, mesh absolute)."""
    shape: dict[str, Any]
    if item.shape == "box":
        shape = {"box": np.asarray(item.extents).tolist()}
    elif item.shape == "sphere":
        shape = {"sphere": item.radius}
    elif item.shape == "cylinder":
        shape = {"cylinder": [item.radius, item.height]}
    else:
        shape = {"mesh": str(item.mesh_path), "scale": item.scale}
    return {"name": item.name, **shape, "world_T_object": _pose(item.world_T_object)}


def _pose(T: Array) -> dict[str, Any]:
    return {"matrix": np.asarray(T, dtype=float).tolist()}


def _system_dict(system: System, model: SystemModel, scn: LoadedScenario) -> dict[str, Any]:
    robots = []
    for r, rm in zip(system.robots, model.robots, strict=True):
        kind = {"model": "ur5e"} if rm.urdf is None else {"urdf": str(scn.resolve_path(rm.urdf))}
        limits = {k: getattr(r.limits, k).tolist() for k in LIMIT_KEYS}
        mirror = {
            "flange_T_mirror": _pose(r.mirror.flange_T_mirror),
            "size": list(r.mirror.size),
            "roi_margin": r.mirror.roi_margin,
        }
        robots.append(
            {"name": r.name, **kind, "world_T_base": _pose(r.world_T_base)}
            | {"home": r.home.tolist(), "limits": limits, "mirror": mirror}
        )
    out: dict[str, Any] = {
        "laser": {"world_T_laser": _pose(system.world_T_laser)},
        "robots": robots,
    }
    if system.camera is not None:
        k = system.camera.intrinsics
        intrinsics = {"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy}
        intrinsics |= {"cx": k.cx, "cy": k.cy}
        cam = system.camera
        mount: dict[str, Any] = {"world_T_camera": _pose(cam.world_T_camera)}
        if cam.robot is not None and cam.flange_T_camera is not None:
            mount = {"robot": cam.robot, "flange_T_camera": _pose(cam.flange_T_camera)}
        out["camera"] = mount | {"intrinsics": intrinsics}
    return out


def resolved_scenario_dict(scn: LoadedScenario) -> dict[str, Any]:
    """The validated scenario with defaults filled in and every pose as ``{matrix: 4x4}``.

    Includes are already applied (``include: []``); ``urdf`` and ``mesh`` paths are
    absolute; ``truth.system`` (if any) is the full merged truth system. Validates again as
    a :class:`~schemas.scenario.Scenario` (plan.json ``scenario``).
    """
    m = scn.model
    out: dict[str, Any] = {
        "name": scn.name,
        "system": _system_dict(system_from_scenario(scn), m.system, scn),
        "scene": [_item_dict(item) for item in scene_objects(scn)],
        "keep_out": [_item_dict(item) for item in keep_out_objects(scn)],
        "safety": m.safety.model_dump(),
        "targets": m.targets.model_dump(exclude_none=True),
        "solver": m.solver.model_dump(),
        "trajectory": m.trajectory.model_dump(),
        "include": [],
    }
    if scn.truth_system is not None:
        truth = system_from_scenario(scn, truth=True)
        out["truth"] = {"system": _system_dict(truth, scn.truth_system, scn)}
    return out
