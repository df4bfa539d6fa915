"""The pure side of the planner node: TargetRequest -> world targets -> plan.json (no Zenoh).

:class:`RequestHandler` turns a validated :class:`~schemas.messages.TargetRequest` into
world-frame :class:`~planner.model.system.Targets` (camera-frame points through the calibrated
``world_T_camera``; path requests resampled every ``PATH_SPACING`` m) and a :class:`~planner.io.plan.Plan`
through a *plan function* ``plan_fn(targets, start, trajectory) -> dict``: ``start`` is
``{robot: q}`` (rad, the robots' current joints) or None for the scenario's home;
``trajectory`` says whether to time a trajectory from ``start``. :func:`make_plan_fn` builds
it over :mod:`planner.plan.pipeline` and :mod:`planner.path.timing`.
"""

from __future__ import annotations

import contextlib
import json
import re
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from planner.beam.trace import trace_beam
from planner.bus.bodies import safe_text
from planner.bus.session import decode, encode
from planner.errors import BeamrelayError, InputError
from planner.io.plan import Plan
from planner.io.strokes import mark_path
from planner.model.settings import TrajectorySettings
from planner.model.system import System, Targets
from planner.model.transforms import Array, transform_points
from planner.plan.landing import surface_tolerance
from planner.service.execution import ExecuteError
from schemas import defaults
from schemas.messages import MAX_ID_LENGTH, MAX_REQUEST_POINTS, ErrorReply, TargetRequest

if TYPE_CHECKING:
    from planner.model.scene import SceneModel
    from planner.plan.pipeline import Pipeline
    from planner.safety.model import Safety
    from planner.service.closed_loop import ClosedLoopConfig
    from schemas.messages import TargetRequest


class PlanFn(Protocol):
    """``plan_fn(targets, start, trajectory, dwell=None, rate=None) -> Plan``:
    ``dwell`` (s) overrides the scenario's ``trajectory.dwell`` (a request's ``dwell``),
    ``rate`` (Hz) its ``trajectory.rate`` (a preview's coarser trajectory)."""

    def __call__(
        self,
        targets: Targets,
        start: dict[str, Array] | None,
        trajectory: bool,
        dwell: float | None = None,
        rate: float | None = None,
    ) -> Plan: ...


#: Hz: the trajectory of a plan that is not executed (a preview) is timed and checked at this
#: rate, a fifth of the servo rate: the console's preview shows the motion and its laser-on
#: path at a fifth of the cost; what is executed is planned again and checked at the
#: scenario's ``trajectory.rate``
PREVIEW_RATE = defaults.SERVO_RATE_HZ / 5


#: path requests are resampled every PATH_SPACING m, at most MAX_PATH_SAMPLES samples
PATH_SPACING = defaults.PATH_SPACING_M
MAX_PATH_SAMPLES = 2000


#: longest error text in a reply (characters)
MAX_ERROR_TEXT = 2000
#: the reply when even an error reply cannot be built
FALLBACK_ERROR = (
    b'{"schema": "beamrelay.error/1", "id": null, '
    b'"error": "internal error while building the error reply", "field": null}'
)


def error_body(exc: BaseException, request_id: str | None = None) -> bytes:
    """An :class:`~schemas.messages.ErrorReply` JSON body for any error, always valid UTF-8
    JSON: texts are made safe (lone surrogates escaped) and cut to :data:`MAX_ERROR_TEXT`.
    ``field`` is the offending key path of an InputError, ``execute`` for a refused
    execution, else null."""

    try:
        field = None
        if isinstance(exc, InputError):
            text = exc.reason
            field = safe_text(exc.where, 300) if exc.where else None
        elif isinstance(exc, ExecuteError):
            text, field = exc.reason, "execute"
        elif isinstance(exc, BeamrelayError):
            text = str(exc)
        else:
            text = f"{type(exc).__name__}: {exc}"
        rid = None if request_id is None else safe_text(request_id, 256)
        msg = ErrorReply(id=rid, error=safe_text(text, MAX_ERROR_TEXT), field=field)
        return encode(msg)
    except Exception:  # the error of an error: never let it escape the worker
        return FALLBACK_ERROR


def request_id_of(payload: bytes) -> str | None:
    """Best effort: the ``id`` of a (possibly invalid) request body, for error replies;
    None when it cannot be found or is not a string. A large body is not parsed again (that
    would hold the GIL): its ``id`` is looked for among its first 64 KiB."""

    try:
        if len(payload) > PRESCAN_BYTES:
            found = re.search(rb'"id"\s*:\s*("(?:[^"\\]|\\.){0,1024}")', payload[:65536])
            rid = json.loads(found.group(1)) if found else None
        else:
            data = json.loads(payload, parse_int=lambda _: 0)  # numbers do not matter here
            rid = data.get("id") if isinstance(data, dict) else None
    except (ValueError, RecursionError):  # JSONDecodeError and UnicodeDecodeError included
        return None
    return safe_text(rid, 256) if isinstance(rid, str) else None


#: bodies larger than this (bytes) are checked by :func:`prescan_request` before parsing
PRESCAN_BYTES = 256 * 1024


def prescan_request(payload: bytes) -> None:
    """Refuse a large body whose structure no TargetRequest has, before parsing it.

    The C JSON parser holds the GIL while it builds lists, objects, strings and literals
    (0.6 s for 4 MB of ``[]``), which would silence the heartbeat thread; numbers go through
    Python hooks and are harmless. Counts are upper bounds (a ``[`` inside a string counts).
    """

    limits = {
        b"[": (2 * MAX_REQUEST_POINTS + 8, "lists"),
        b"{": (16, "objects"),
        b'"': (4 * MAX_ID_LENGTH + 64, "quotes"),
        b"true": (16, "true literals"),
        b"false": (16, "false literals"),
        b"null": (16, "null literals"),
    }
    if not payload.isascii():
        try:
            payload.decode("utf-8")
        except UnicodeDecodeError:
            return  # not text: decode() says so
    for token, (limit, what) in limits.items():
        n = payload.count(token)
        if n > limit:
            raise InputError(
                f"{n} {what} in a {len(payload)}-byte body: a request has at most {limit}",
                "body",
            )


def make_plan_fn(
    system: System,
    scenario: dict[str, Any],
    options: Any = None,
    settings: TrajectorySettings | None = None,
    scene: SceneModel | None = None,
    safety: Safety | None = None,
) -> PlanFn:
    """The node's plan function over :mod:`planner.plan.pipeline` for one (calibrated) system.

    ``scenario`` is the resolved scenario dict echoed in every plan; ``options`` an
    :class:`~planner.ik.IKOptions`; ``settings`` the scenario's ``trajectory`` section. Points
    are solved in order, each seeded by the previous solution (the first by ``start``); the
    trajectory starts at ``start`` (the robots' current joints) instead of home. Solutions
    are re-verified (:func:`~planner.plan.document.verify_solutions`: the checks of ``beamrelay
    check`` on the resolved ``scenario``) *before* the trajectory is timed, so a rejected
    one is never part of it. ``scene`` (a :class:`~planner.model.scene.SceneModel`) makes
    beams that cross it fail as ``occluded`` (camera-frame point targets land on the surface
    that carries them first: the plan's ``targets`` are the landed points); ``safety`` (:class:`~planner.safety.model.Safety`)
    applies the collision, keep-out and clearance rules to the solutions and the trajectory.
    """
    from planner.ik import IKOptions
    from planner.plan.pipeline import Pipeline
    from planner.plan.scenario_planner import ScenarioPlanner

    # the targets carry their own surface tolerance (the handler's, for camera-frame ones)
    rules = ScenarioPlanner(system, options or IKOptions(), scene, safety, 0.0)
    return pipeline_plan_fn(Pipeline(rules, scenario, settings or TrajectorySettings()))


def pipeline_plan_fn(pipeline: Pipeline) -> PlanFn:
    """The node's plan function over ``pipeline`` (a :class:`~planner.plan.pipeline.Pipeline`):
    what :func:`make_plan_fn` describes."""
    from planner.plan.document import build_plan

    system, scenario, timing = pipeline.rules.system, pipeline.scenario, pipeline.settings
    scene = pipeline.rules.scene

    def plan_fn(
        targets: Targets,
        start: dict[str, Array] | None,
        trajectory: bool,
        dwell: float | None = None,
        rate: float | None = None,
    ) -> Plan:
        q0 = None if start is None else system.stack_q(start)
        timing_now, scn_now = timing, scenario
        changed: dict[str, float] = {}
        if dwell is not None:
            timing_now, changed["dwell"] = replace(timing_now, dwell=dwell), dwell
        if rate is not None and rate < timing.rate:  # never finer than the scenario's
            timing_now, changed["rate"] = replace(timing_now, rate=rate), rate
        if changed:  # the plan echoes the dwell and rate it was timed with
            scn_now = {**scenario, "trajectory": {**scenario.get("trajectory", {}), **changed}}
        targets, sols, _ = pipeline.solve(targets, q0)  # re-verified: a rejected one not visited
        traj = None
        if trajectory:  # from the robots' current joints, in the requested order
            timed, sols, _, _ = pipeline.time(targets, sols, None, timing_now, q_start=q0)
            traj = None if timed is None else timed.trajectory.to_plan(system)
        plan = build_plan(system, targets, sols, scn_now, traj, verify=False)
        if targets.kind != "path" and scene is not None and not scene.empty:
            plan = with_surface_warnings(plan, targets.points, scene)
        return plan

    return plan_fn


#: m: a point target farther than this from every scene surface gets a warning
OFF_SURFACE = 0.005


def with_surface_warnings(plan: Plan, points: Array, scene: Any) -> Plan:
    """``plan`` warning (``warnings``, one line each) about targets farther than
    :data:`OFF_SURFACE` from every surface of ``scene`` (a SceneModel): the spot lands
    where the beam meets a surface, not on a target in mid-air; the largest distance in
    ``metrics.extra.surface_distance_max`` (m)."""
    dist, obj = scene.nearest_surface(points)
    plan = replace(plan, metrics=plan.metrics.with_extra(surface_distance_max=float(dist.max())))
    far = np.flatnonzero(dist > OFF_SURFACE)
    if not len(far):
        return plan
    names = scene.names
    lines = [f"target {int(k)} is {1e3 * dist[k]:.1f} mm from the nearest surface "
             f"({names[obj[k]]}): the spot lands where the beam meets a surface"
             for k in far[:5]]  # fmt: skip
    if len(far) > 5:
        lines.append(f"... and {len(far) - 5} more targets off every surface")
    return replace(plan, warnings=tuple(lines))


def handler_from_scenario(path: Any, extra_includes: tuple[Any, ...] = ()) -> RequestHandler:
    """A :class:`RequestHandler` for a scenario file (calibration applied via ``include:``;
    ``extra_includes`` after the scenario's own, e.g. the online calibration file)."""
    from planner.io.scenario import load_scenario
    from planner.plan.pipeline import Pipeline
    from planner.service.closed_loop import closed_loop_config

    scn = load_scenario(path, extra_includes)
    pipeline = Pipeline.from_scenario(scn)  # the pipeline `beamrelay plan` and the API use
    rules, settings = pipeline.rules, pipeline.settings
    system, safety, model = rules.system, rules.safety, scn.model
    plan_fn = pipeline_plan_fn(pipeline)
    laser = model.system.laser
    gated = laser.gate is not None
    # ungated (simulation only: --backend ur needs a gate), the laser is always on: there is
    # no treatment gate to keep off, so the measurements need no aiming beam of their own
    closed = closed_loop_config(system, settings, safety, gated, laser.aim is not None or not gated)
    tracker = track_ik(system, rules.options, safety)
    return RequestHandler(system, plan_fn, closed_loop=closed, track_ik=tracker,
                          surface_tolerance=rules.surface_tolerance)  # fmt: skip


def track_ik(system: System, options: Any, safety: Safety | None) -> Any:
    """The IK that follows ``mode: track`` targets (closed form with the safety rules), or
    None when an arm has no analytic seed model."""
    from planner.ik import BeamIK

    ik = BeamIK(system, options, safety)
    return ik if ik.closed_form is not None else None


def camera_to_world(
    system: System, points: Array, normals: Array | None, q: Any = None
) -> tuple[Array, Array | None]:
    """Camera-frame points and normals (m, optical frame) in the world through the
    calibrated camera pose at joints ``q`` (:meth:`System.world_T_camera`); InputError
    naming ``frame`` without a camera."""
    if system.camera is None:
        raise InputError("frame is camera but the scenario has no camera", "frame")
    world_T_camera = system.world_T_camera(q)
    points = transform_points(world_T_camera, points)
    return points, None if normals is None else normals @ world_T_camera[:3, :3].T


@dataclass
class RequestHandler:
    """TargetRequest -> :class:`~planner.io.plan.Plan`; pure (no Zenoh), used by the node and the tests."""

    system: System
    plan_fn: PlanFn
    path_spacing: float = PATH_SPACING
    closed_loop: ClosedLoopConfig | None = None
    """closed-loop execution (:mod:`planner.service.closed_loop`); None: refused"""
    track_ik: Any = None  # a BeamIK for ``mode: track`` (None: tracking refused)
    surface_tolerance: float = field(default_factory=surface_tolerance)
    """m: how far a camera-frame point target may lie from the surface that carries it
    (:mod:`planner.plan.landing`)"""

    def targets(self, req: TargetRequest, start: dict[str, Array] | None = None) -> Targets:
        """World-frame targets of a validated TargetRequest (points in metres); camera-frame
        points through the calibrated camera pose at ``start`` (rad per robot; None: home,
        which only an eye-in-hand camera's pose depends on)."""
        points = np.asarray(req.points, dtype=float).reshape(-1, 3)
        normals = None if req.normals is None else np.asarray(req.normals, dtype=float)
        tol = 0.0  # world targets are exact; camera-frame ones land on their surface
        if req.frame == "camera":
            points, normals = camera_to_world(self.system, points, normals, start)
            tol = self.surface_tolerance
        if req.mode != "path":
            return Targets(points, normals, kind="points", surface_tolerance=tol)

        length = float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))
        if length / self.path_spacing > MAX_PATH_SAMPLES:
            raise InputError(
                f"path of {length:.3f} m needs more than {MAX_PATH_SAMPLES} samples "
                f"at {1e3 * self.path_spacing:g} mm spacing",
                "points",
            )
        # corners above the default corner angle are marked sharp, as in scenarios; an
        # InputError names the request's field (points or normals)
        marked = mark_path(points, self.path_spacing, normals=normals)
        return Targets(marked.points, marked.normals, kind="path", meta=marked.meta(),
                       surface_tolerance=tol)  # fmt: skip

    def parse(self, payload: bytes) -> Any:
        """Validate a request body (raises InputError naming the field)."""

        if len(payload) > PRESCAN_BYTES:
            prescan_request(payload)
        try:
            return decode(payload, TargetRequest)
        except RecursionError as exc:  # json.loads on absurdly deep nesting
            raise InputError("JSON nested too deeply", "body") from exc

    def plan(
        self, req: TargetRequest, start: dict[str, Array] | None = None, trajectory: bool = False,
        rate: float | None = None,
    ) -> Plan:  # fmt: skip
        """The plan of a validated request, starting at ``start`` (rad) or home, its
        trajectory timed at ``rate`` (Hz; None: the scenario's)."""
        targets = self.targets(req)
        if rate is None:  # the scenario's rate (a plan function may take no ``rate``)
            return self.plan_fn(targets, start, trajectory)
        return self.plan_fn(targets, start, trajectory, rate=rate)

    def warm_up(self) -> float:
        """Plan one target with its trajectory, 0.5 m down the beam at home (reached where
        the arm rests), then a short path through it across the beam (:func:`warm_up_path`),
        and drop the plans: CasADi's functions load, IPOPT builds its solvers and the path's
        warm start, NLP and timing load their modules before the first request, which
        otherwise pays for them (the console's first click-to-preview took 2.3 s, the next
        ones 0.1-0.2 s; the first path 0.5 s more than the next, scipy's import alone).
        Seconds it took; a plan that fails is no error here."""

        t0 = time.perf_counter()
        beam = trace_beam(self.system, self.system.home, np.zeros(3))
        target = beam.hits[-1] + 0.5 * beam.dirs[-1]
        for points, mode in (([target], "points"), (warm_up_path(target, beam.dirs[-1]), "path")):
            req = TargetRequest.model_validate({
                "schema": "beamrelay.request/1", "id": "warm-up", "mode": mode, "frame": "world",
                "points": [p.tolist() for p in points], "execute": False, "trajectory": True,
            })  # fmt: skip
            with contextlib.suppress(BeamrelayError):
                self.plan(req, None, trajectory=True)
        return time.perf_counter() - t0


def warm_up_path(centre: Array, beam: Array) -> list[Array]:
    """The ends of the warm-up's path: a line through ``centre`` (world, m) across the unit
    ``beam`` direction, just long enough for the coarse-to-fine warm start of
    :func:`planner.path.solve.plan_path` (four coarse steps)."""
    from planner.path.nlp import PathOptions

    across = np.cross(beam, [0.0, 0.0, 1.0])
    if np.linalg.norm(across) < 1e-6:  # a vertical beam
        across = np.cross(beam, [1.0, 0.0, 0.0])
    half = 2.0 * PathOptions().coarse_spacing * across / np.linalg.norm(across)
    return [centre - half, centre + half]
