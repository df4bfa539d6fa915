"""Simulated RGB-D camera (backend ``sim``): the scenario's scene seen by a D435 model.

Point cloud: the scene objects (:func:`planner.io.scenario.scene_objects`: box, mesh, sphere,
cylinder, in the world) go into one open3d ``RaycastingScene``; one ray per pixel (every
``stride``-th pixel) from the *true* camera pose (``truth:`` system) gives the noiseless
depth z (m, along the optical axis). Static objects are raycast once; an object with a
``motion:`` (:mod:`drivers.camera.moving`) is cast again every frame at the frame's time
(``clock()``, UNIX s by default), only for the pixels whose rays meet its swept box. Every
frame redraws the D435 depth noise, Gaussian along the pixel's ray with

    sigma_z = z^2 * subpixel / (fx * baseline),   subpixel = 0.08 px, baseline = 0.050 m

(Intel's RMS-error model; 1.3 mm at 0.6 m with fx = 430 px), independent per pixel. With
``depth_errors`` (:class:`planner.model.d435.DepthErrors`, one physical camera's) the noise
is correlated between neighbouring pixels as the D4's census matching makes it (unit white
noise box-filtered over ``CENSUS_PX`` x ``CENSUS_PX`` pixels of the full image, then scaled
by sigma_z: correlation (1 - |du|/9)(1 - |dv|/9)) and every depth carries the camera's fixed
bias (:func:`planner.model.d435.biased_depth` of its disparity offset). Points are in the
camera optical frame (x right, y down, z forward), float32; pixels that see nothing are
dropped.

Laser spot: only while the laser is on. With a gate (the scenario's ``laser.gate``,
``gated``) that is while the last :class:`schemas.messages.LaserState` on ``<prefix>/laser``
(published by the gate robot's driver at every switch) says ``on`` or ``aim`` (the coaxial
aiming beam lands where the treatment beam would), off before any; without
one the laser counts as always on. The *true* beam - the latest joint states of every robot traced with the
``truth:`` geometry (:class:`planner.beam.graph.BeamModel`) - must be a valid reflection chain
(ahead, front face, inside each ROI), else no spot. Each beam segment is raycast against the
scene at the frame's time (an object in the way catches the beam there: a moving object
where it is then), the last one gives the spot. It must be
inside the image and visible from the camera (no object between), else no spot. The
detection deprojects the spot's centroid pixel (noise ``SIGMA_PX`` =
:data:`planner.model.d435.SPOT_PX` per axis) with
the depth of a plane fitted to the ``SPOT_WINDOW`` x ``SPOT_WINDOW`` pixels around it (noise
``sigma_z / SPOT_WINDOW`` along the ray): 0.2 mm at 0.87 m, the paper_n1 camera distance
(the one D435 model, :data:`planner.model.d435.SPOT`);
confidence = |cos| of the angle between the beam and the surface normal (a grazing beam
makes a long, dim spot), at least 0.05. Like the RealSense driver's gated detector, it looks
for the spot only within :attr:`SpotParams.radius <drivers.camera.spot.SpotParams.radius>`
px of the planner's predicted spot (``<prefix>/camera/predicted``, :meth:`SimCamera.on_predicted`)
while that prediction is fresh (:data:`drivers.camera.spot.PREDICTION_TTL`); a spot outside
the window is not detected (counted in :attr:`SimCamera.outside_window`). With
``depth_errors`` the spot and the markers carry the camera's bias and the window statistics of
correlated pixels (:meth:`planner.model.d435.D435Noise.with_errors`; the spot's depth is the
window's median, as in :mod:`drivers.camera.realsense`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.camera.moving import MovingScene
from drivers.camera.node import SpotReading
from drivers.camera.spot import PREDICTION_TTL, SpotParams, project
from planner.beam.graph import BeamModel
from planner.errors import InputError
from planner.model import d435
from planner.model.scene import SceneItem, SceneModel
from planner.model.system import Camera, System
from planner.model.transforms import Array, inv_T

SIGMA_PX = d435.SPOT_PX  # px, noise of the spot centroid per image axis
SPOT_WINDOW = d435.SPOT_WINDOW  # px, side of the window whose plane fit gives the spot depth
depth_sigma = d435.depth_sigma
EPS = 1e-6  # m, offset of a ray start off the surface it leaves
F32 = NDArray[np.float32]


def build_scene(items: list[SceneItem]) -> Any:
    """An open3d ``RaycastingScene`` of the scene objects, in the world frame (the planner's
    :class:`planner.model.scene.SceneModel`, so the camera and the occlusion check see one scene)."""

    return SceneModel(items).raycasting_scene


def pixel_grid(camera: Camera, stride: int = 1) -> tuple[Array, Array]:
    """Pixel centres (u, v) of every ``stride``-th pixel, and their rays (x/z, y/z, 1)."""
    k = camera.intrinsics
    u, v = np.meshgrid(np.arange(0, k.width, stride), np.arange(0, k.height, stride))
    uv = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    rays = np.column_stack([(uv[:, 0] - k.cx) / k.fx, (uv[:, 1] - k.cy) / k.fy, np.ones(len(uv))])
    return uv, rays


def render_depth(scene: Any, camera: Camera, stride: int = 1) -> tuple[Array, Array]:
    """Noiseless depth z (m, inf = nothing) of every ``stride``-th pixel and its ray."""
    import open3d as o3d

    _, rays_c = pixel_grid(camera, stride)
    R, c = camera.world_T_camera[:3, :3], camera.world_T_camera[:3, 3]
    rays = np.hstack([np.broadcast_to(c, rays_c.shape), rays_c @ R.T]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
    return hit["t_hit"].numpy().astype(float), rays_c  # t along (x/z, y/z, 1) is z


#: s: joint states older than this do not set a frame's time (their robot went silent)
STAMP_WINDOW = 0.5


class SimCamera:
    """Camera source for :class:`drivers.camera.node.CameraNode` (see module docstring).

    ``system`` is the *true* system (``system_from_scenario(scn, truth=True)``); it must
    have a camera. ``clock`` gives the simulation time (s) of a frame, read in :meth:`grab`.
    """

    kind = "sim"

    def __init__(
        self, system: System, items: list[SceneItem], *, stride: int = 1, seed: int | None = None,
        gated: bool = False, clock: Callable[[], float] = time.time,
        depth_errors: d435.DepthErrors | None = None,
    ) -> None:  # fmt: skip

        if system.camera is None:
            raise InputError(
                "the camera driver needs system.camera in the scenario", "system.camera"
            )
        self.system = system
        self.camera: Camera = system.camera
        self.stride = stride
        self.depth_errors = depth_errors
        self.rng = np.random.default_rng(seed)
        self.world = MovingScene(items)
        self.scene = self.world.static.raycasting_scene  # the objects that never move
        self.clock = clock
        self.t = clock()
        self.beam = BeamModel(system)
        self.robot_names = system.robot_names
        self.q: dict[str, Array] = {}
        self.q_stamp: dict[str, float] = {}
        self.gated = gated
        self.laser = False  # the gate's last published state (off until told otherwise)
        z, rays = render_depth(self.world.static.raycasting_scene, self.camera, stride)
        self._z_static, self._rays_all = z, rays
        self._watch = [self._swept_pixels(j) for j in range(len(self.world.moving))]
        ok = np.isfinite(z)
        self._ok = ok
        self._z = z[ok].astype(np.float32)
        self._rays = rays[ok].astype(np.float32)
        self._sigma = depth_sigma(self._z, self.camera.intrinsics.fx).astype(np.float32)
        self.camera_T_world = inv_T(self.camera.world_T_camera)
        self._last: tuple[Array, tuple[Array, Array, Array] | None] | None = None
        self._predicted: tuple[Array, float] | None = None  # camera frame m, UNIX s
        self.window_px = SpotParams().radius
        self.outside_window = 0  # spots not detected: outside the predicted spot's window

    def on_predicted(self, p_camera: Array, t: float) -> None:
        """The planner's predicted spot (camera optical frame, m) at UNIX time ``t``."""
        self._predicted = (np.asarray(p_camera, dtype=float), float(t))

    def _in_window(self, u: float, v: float) -> bool:
        """Whether pixel (u, v) is inside the detector's search window (the whole image
        without a fresh prediction)."""
        if self._predicted is None or self.clock() - self._predicted[1] > PREDICTION_TTL:
            return True
        p, k = self._predicted[0], self.camera.intrinsics
        if p[2] <= 0:
            return True
        pu, pv = project(p, k.fx, k.fy, k.cx, k.cy)
        return bool(np.hypot(u - pu, v - pv) <= self.window_px)

    def _swept_pixels(self, j: int) -> Any:
        """Indices of the pixel rays that meet moving object ``j``'s swept box."""

        box = SceneModel([self.world.swept_box(j)])
        c, R = self.camera.world_T_camera[:3, 3], self.camera.world_T_camera[:3, :3]
        dirs = self._rays_all @ R.T
        t = box.cast(np.broadcast_to(c, dirs.shape), dirs).t
        return np.flatnonzero(np.isfinite(t))

    def depth(self) -> tuple[F32, F32]:
        """Noiseless depth z (m) of the pixels that see something at the frame's time, and
        their rays (x/z, y/z, 1), camera frame."""
        if not self.world.has_motion:
            return self._z, self._rays
        z, ok = self._depth_all()
        return z[ok].astype(np.float32), self._rays_all[ok].astype(np.float32)

    def _depth_all(self) -> tuple[Array, Array]:
        """Noiseless depth of every ``stride``-th pixel at the frame's time (inf: nothing)
        and the mask of those that see something."""
        if not self.world.has_motion:
            return self._z_static, self._ok
        z = self._z_static.copy()
        c, R = self.camera.world_T_camera[:3, 3], self.camera.world_T_camera[:3, :3]
        for j, idx in enumerate(self._watch):
            dirs = self._rays_all[idx] @ R.T
            zj = self.world.object_cast(j, np.broadcast_to(c, dirs.shape), dirs, self.t)
            z[idx] = np.minimum(z[idx], zj)
        return z, np.isfinite(z)

    def correlated_field(self) -> Array:
        """Unit-variance noise of every ``stride``-th pixel (in :func:`pixel_grid` order),
        correlated as the D4's census window makes it: white noise on the full image
        box-filtered over ``CENSUS_PX`` x ``CENSUS_PX`` pixels."""
        k, m = self.camera.intrinsics, d435.CENSUS_PX
        white = self.rng.standard_normal((k.height + m - 1, k.width + m - 1))
        c = np.pad(np.cumsum(np.cumsum(white, axis=0), axis=1), ((1, 0), (1, 0)))
        box = c[m:, m:] - c[:-m, m:] - c[m:, :-m] + c[:-m, :-m]  # m x m sums, height x width
        return (box[:: self.stride, :: self.stride] / m).ravel()

    def frame_time(self) -> float:
        """The simulation time (s) of the current frame (set by :meth:`grab`)."""
        return self.t

    def on_joint_state(self, robot: str, q: Array, t: float | None = None) -> None:
        """Latest measured joints of one robot (rad), stamped ``t`` (UNIX s) when known."""
        self.q[robot] = np.asarray(q, dtype=float)
        if t is not None:
            self.q_stamp[robot] = float(t)

    def on_laser(self, on: bool) -> None:
        """The laser gate's state (``<prefix>/laser``)."""
        self.laser = bool(on)

    def grab(self) -> None:
        """Start a frame: read its time from the clock (the scene is rendered on demand).
        The frame shows the robots at the joint states it has, which arrive over the bus a
        little late (more on a loaded machine): it is stamped with their time, as a real
        camera's frame is stamped when the arm was where the frame shows it (unless they
        are older than :data:`STAMP_WINDOW`: a silent robot)."""
        now = self.clock()
        stamps = [self.q_stamp[r] for r in self.robot_names if r in self.q_stamp]
        oldest = min(stamps, default=now)
        self.t = min(now, oldest) if now - oldest < STAMP_WINDOW else now

    def points(self) -> tuple[F32, dict[str, Any]]:
        """One noisy cloud (M x 3 float32, camera frame) and its metadata."""
        errors = self.depth_errors
        if errors is not None and (errors.correlated or errors.disparity_offset_px):
            pts = self._points_with_errors(errors)
        else:
            z0, rays = self.depth()
            if self.world.has_motion:
                sigma = depth_sigma(z0, self.camera.intrinsics.fx).astype(np.float32)
            else:
                sigma = self._sigma
            z = z0 + sigma * self.rng.standard_normal(len(z0), dtype=np.float32)
            pts = rays * z[:, None]
        k = self.camera.intrinsics
        meta = {"width": k.width, "height": k.height, "stride": self.stride, "organized": False}
        return pts, meta

    def _points_with_errors(self, errors: d435.DepthErrors) -> F32:
        """The cloud with the camera's bias and (when correlated) correlated pixel noise."""
        z_all, ok = self._depth_all()
        z0, fx = z_all[ok], self.camera.intrinsics.fx
        unit = (
            self.correlated_field()[ok] if errors.correlated else self.rng.standard_normal(len(z0))
        )
        z = d435.biased_depth(z0, errors.disparity_offset_px, fx) + depth_sigma(z0, fx) * unit
        return (self._rays_all[ok] * z[:, None]).astype(np.float32)

    def true_spot_world(self) -> tuple[Array, Array, Array] | None:
        """Noiseless spot in the world, the beam direction and surface normal there, or None
        (also while a gated laser is off)."""
        if self.gated and not self.laser:
            return None
        if not all(r in self.q for r in self.robot_names):
            return None
        q = self.system.stack_q(self.q)
        static = not self.world.moving  # a moving object moves the spot at fixed joints
        if static and self._last is not None and np.array_equal(self._last[0], q):
            return self._last[1]  # the scene is static: same joints, same spot
        hit = self._trace_spot(q)
        self._last = (q, hit)
        return hit

    def _trace_spot(self, q: Array) -> tuple[Array, Array, Array] | None:
        """The true beam at stacked joints ``q`` onto the scene (see :meth:`true_spot_world`)."""
        tr = self.beam.trace(q)
        if not (np.all(tr.front > 0) and np.all(tr.ahead > 0) and np.all(tr.roi >= 0)):
            return None
        starts = [self.system.world_T_laser[:3, 3], *tr.hits]
        for i, (p, v) in enumerate(zip(starts, tr.dirs, strict=True)):
            t_max = np.linalg.norm(tr.hits[i] - p) if i < len(tr.hits) else np.inf
            t_hit, normal = self._cast(p, v)
            if t_hit < t_max - EPS:  # caught by an object before the next mirror (or the last ray)
                return p + t_hit * v, v, normal
        return None

    def spot(self) -> SpotReading | None:
        """Detected spot (noisy, camera frame) or None."""
        hit = self.true_spot_world()
        if hit is None:
            return None
        spot_w, v, normal = hit
        c = self.camera.world_T_camera[:3, 3]
        to_spot = spot_w - c
        dist = float(np.linalg.norm(to_spot))
        t_hit, _ = self._cast(c, to_spot / dist)
        if t_hit < dist - 1e-4:  # something hides the spot from the camera
            return None
        p_c = self.camera_T_world[:3, :3] @ spot_w + self.camera_T_world[:3, 3]
        k = self.camera.intrinsics
        if p_c[2] <= 0:
            return None
        u, w = k.fx * p_c[0] / p_c[2] + k.cx, k.fy * p_c[1] / p_c[2] + k.cy
        if not (0 <= u < k.width and 0 <= w < k.height):
            return None
        if not self._in_window(u, w):
            self.outside_window += 1
            return None
        spot = d435.SPOT.with_focal(k.fx).with_errors(self.depth_errors, median=True)
        p_noisy = spot.apply(p_c, self.rng)
        confidence = max(0.05, abs(float(np.dot(v, normal))))
        return SpotReading(p_noisy, min(confidence, 1.0))

    def markers(self, request: dict[str, Any]) -> Array:
        """Board markers in the camera frame (P x 3, m; NaN outside the image), for hand-eye
        collection. The simulated camera renders no board: the request gives the board's
        points and its true mount (``board_pose``: ``flange_T_board`` on ``robot``, the
        eye-to-hand setup), and the markers are placed from the latest joint states with the
        truth geometry plus the D435 corner noise (:data:`planner.model.d435.CORNER`; no
        occlusion check)."""
        board = np.asarray(request["board_points"], dtype=float).reshape(-1, 3)
        pose = np.asarray(request["board_pose"], dtype=float).reshape(4, 4)
        robot = str(request["robot"])
        if robot not in self.q:
            raise ValueError(f"no joint state of {robot!r} yet")
        r = self.system.robot(robot)
        c_T_b = self.camera_T_world @ r.world_T_base @ r.kinematics.fk(self.q[robot]) @ pose
        p = board @ c_T_b[:3, :3].T + c_T_b[:3, 3]
        k = self.camera.intrinsics
        p = d435.CORNER.with_focal(k.fx).with_errors(self.depth_errors).apply(p, self.rng)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = k.fx * p[:, 0] / p[:, 2] + k.cx, k.fy * p[:, 1] / p[:, 2] + k.cy
        seen = (p[:, 2] > 0.1) & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
        p[~seen] = np.nan
        return p

    def _cast(self, p: Array, v: Array) -> tuple[float, Array]:
        """Distance along unit ray (p, v) to the scene at the frame's time (inf = miss) and
        the surface normal."""
        hit = self.world.cast((p + EPS * v)[None], np.asarray(v)[None], self.t)
        return float(hit.t[0]) + EPS, hit.normal[0]

    def close(self) -> None:
        """Nothing to release."""
