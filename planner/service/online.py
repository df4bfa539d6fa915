"""The planner node's online calibration: collect measured spots, refit in the background,
publish, write the includable file, and swap the planner's system between requests.

:class:`OnlineCalibrator` is opt-in (``beamrelay serve|up --online-calibration FILE``). It
takes samples from two sources, both thread safe and never raising on bad input (a bad
sample is logged, counted in :attr:`OnlineCalibrator.rejected` and dropped):

- :meth:`OnlineCalibrator.add_sample` ``(q, spot_world)`` - the API for the closed-loop servo
  and anything else that measured a spot at known joints: ``q`` is ``{robot: joints}`` (rad)
  of every robot, ``spot_world`` the spot in the world (m);
  :meth:`OnlineCalibrator.add_camera_spot` takes the spot in the camera's optical frame and
  maps it through the calibrated camera pose at those joints;
- :class:`RestSampler`, fed by the node's ``<prefix>/camera/spot`` subscription: a spot seen
  on two consecutive frames with every robot at rest at the same joints (and confidence at
  least ``MIN_CONFIDENCE``) is one sample, one per rest configuration.

A background thread refits (:func:`planner.calibration.online.refit`) whenever samples
arrived since the last attempt. An accepted refit is written to FILE (atomically: a
temporary file renamed over it), the scenario is reloaded with FILE as a last ``include:``
(the planner's handler is rebuilt from it, so the file is proven includable), the node
swaps to the new handler *between* requests (a request in progress keeps the system it
started with), and a :class:`~schemas.messages.CalibrationMessage` with the new ``version``
goes out on ``<prefix>/calibration``. A refused refit keeps the calibration in force;
:attr:`OnlineCalibrator.last` holds the reason. Every attempt is one ``refit_accepted`` or
``refit_refused`` event line with its figures (held-out and in-force medians per surface,
the mirror margin and hit std).

Each sample is labelled with the scene object its spot lies on (within ``SURFACE_TOL_M``;
a refit needs held-out samples on two surfaces), and the configurations of the node's
recent plans (:meth:`OnlineCalibrator.add_planned`) join the samples' in the mirror-margin
test of :func:`planner.calibration.online.refit`.

History and rollback: every version is also kept as ``FILE.versions/NNNN.yaml`` (``0000`` is
the calibration in force before the first refit). ``beamrelay calibrate rollback FILE [--to
N]`` (:func:`rollback`) writes a new, higher version holding version N's poses (default: the
one before the refit in force) to FILE and its history; the running node sees FILE change
within ``POLL_S``, installs it like a refit, drops the samples it had (they would refit the
same version again) and publishes it.
"""
# long module: online calibration on the bus: samples at rest, refits and the versions in force share one state

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from planner.beam.trace import trace_beam
from planner.bus.events import event
from planner.bus.session import JSON, MAX_PAYLOAD_BYTES, decode_sample, encode
from planner.calibration.online import (
    Calibration,
    RefitResult,
    SpotSample,
    make_sample,
    refit,
)
from planner.errors import InputError
from planner.io.plan import Plan
from planner.model.scene import SceneModel
from planner.model.status import Status
from planner.model.system import System
from planner.model.transforms import Array, transform_points
from planner.service.online_file import (
    ONLINE_MARK,
    check_poses,
    document_of,
    history,
    history_dir,
    history_lock,
    read_document,
    system_of,
    version_of,
    write_atomically,
)
from schemas.messages import CalibrationMessage, SpotMessage

log = logging.getLogger("beamrelay.online")

MAX_SAMPLES = 400  # newest samples kept for refits (older ones are dropped)
MAX_PLANNED = 64  # newest planned configurations whose mirror hits a refit must keep
SURFACE_TOL_M = 0.01  # m: a spot this close to a scene object lies on it (D435 noise: mm)
POLL_S = 1.0  # s: how often the refit thread looks for a rollback written to FILE
MIN_CONFIDENCE = 0.3  # spot detection confidence a rest sample needs
#: m: a spot farther than this from the current model's beam is not the beam (a reflection,
#: another light, a lying camera): the calibration error it could come from is far smaller
MAX_RAY_DISTANCE = 0.06


def ray_distance(system: Any, q: Array, p: Array) -> float:
    """Distance (m) of the world point ``p`` from the last ray of the beam ``system``
    models at stacked ``q`` (rad); inf when that beam is no valid reflection chain."""

    tr = trace_beam(system, np.asarray(q, dtype=float), np.asarray(p, dtype=float))
    return float(tr.error) if tr.target_ahead > 0 else float("inf")


REST_QD = 1e-3  # rad/s: every joint slower than this counts as at rest
SAME_Q = 1e-5  # rad: joints closer than this (max abs) are the same configuration


class OnlineCalibrator:
    """Samples in, versioned calibrations out (see the module docstring).

    ``nominal`` is the scenario's system (it fixes the gauge); ``out_file`` where accepted
    calibrations go; ``rebuild(out_file)`` returns the planner's new handler (any object);
    ``publish(body)`` sends a JSON body on ``<prefix>/calibration``; ``on_update(handler,
    calibration)`` installs it. ``clock`` gives message times (UNIX s). ``scene`` (the
    scenario's objects) labels each sample with the surface its spot lies on.
    """

    def __init__(
        self,
        nominal: System,
        out_file: Path,
        *,
        rebuild: Callable[[Path], Any] | None = None,
        publish: Callable[[bytes], None] | None = None,
        on_update: Callable[[Any, Calibration], None] | None = None,
        clock: Callable[[], float] = time.time,
        loss_scale: float = 1e-3,
        scene: SceneModel | None = None,
    ) -> None:
        self.nominal = nominal
        self.out_file = Path(out_file)
        self.rebuild, self.publish, self.on_update = rebuild, publish, on_update
        self.clock = clock
        self.loss_scale = loss_scale
        self.scene = scene
        self.current = Calibration(0, nominal)
        self._planned: collections.deque[Array] = collections.deque(maxlen=MAX_PLANNED)
        self._file_seen: tuple[int, int] | None = self._stat()
        #: take samples from ``camera/spot`` at rest (:class:`RestSampler`); a node whose
        #: servo calls :meth:`add_sample` itself may turn it off to avoid duplicates
        self.rest_sampling = True
        self.last: RefitResult | None = None
        self.rejected = 0
        self.implausible = 0  # camera spots dropped: too far from the modelled beam
        self.refits = 0
        self._samples: list[SpotSample] = []
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending = False
        self._closing = False
        self._idle = threading.Event()
        self._idle.set()
        self._thread = threading.Thread(target=self._loop, name="online-calibration", daemon=True)

    # --- samples (any thread) --------------------------------------------------------------
    def add_sample(
        self,
        q: Any,
        spot_world: Any,
        *,
        board: int = 0,
        t: float | None = None,
        surface: str | None = None,
    ) -> bool:
        """Queue one measured spot: ``q`` ``{robot: joints}`` (rad, every robot) or stacked,
        ``spot_world`` (3,) in the world (m); ``surface`` the scene object it lies on
        (default: found in the scene). False (and logged) when it is not valid."""
        try:
            s = make_sample(self.nominal, q, spot_world, board, self.clock() if t is None else t)
            s = dataclasses.replace(s, surface=self.surface_of(s.spot_world) if surface is None
                                    else str(surface))  # fmt: skip
        except InputError as exc:
            self.rejected += 1
            log.warning("online calibration: sample dropped (%s: %s)", exc.where, exc.reason)
            return False
        with self._lock:
            self._samples.append(s)
            del self._samples[:-MAX_SAMPLES]
            self._pending = True
            self._idle.clear()
            self._wake.notify()
        return True

    def add_camera_spot(
        self, q: Any, p_camera: Any, *, board: int = 0, t: float | None = None
    ) -> bool:
        """As :meth:`add_sample` with the spot in the camera optical frame (m), mapped to the
        world with the calibrated camera pose at ``q`` (a flange camera moves with it)."""
        try:
            system = self.current.system
            if system.camera is None:
                raise InputError("camera-frame spot but the scenario has no camera", "p_camera")
            qs = make_sample(self.nominal, q, np.zeros(3)).q
            world_T_camera = system.world_T_camera(system.split_q(qs))
            p = np.asarray(p_camera, dtype=float)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise InputError(f"expected a finite 3D spot (m), got shape {p.shape}", "p_camera")
        except InputError as exc:
            self.rejected += 1
            log.warning("online calibration: sample dropped (%s: %s)", exc.where, exc.reason)
            return False
        spot = transform_points(world_T_camera, p)
        off = ray_distance(system, qs, spot)
        if off > MAX_RAY_DISTANCE:  # not the beam the current model points there
            self.implausible += 1
            log.warning("online calibration: implausible spot dropped (%.1f mm from the "
                        "modelled beam, limit %.0f mm)", 1e3 * off, 1e3 * MAX_RAY_DISTANCE)  # fmt: skip
            return False
        return self.add_sample(qs, spot, board=board, t=t)

    def resume(self) -> bool:
        """Start from the version in FILE, if FILE holds one (a restarted planner, e.g. by
        ``up``'s supervisor, goes on with the calibration it had, not the scenario's); True
        when it did. A FILE that cannot be installed is left alone (logged)."""
        if not self.out_file.is_file():
            return False
        try:
            doc = read_document(self.out_file)
            check_poses(doc, self.out_file)
            cal = Calibration(version_of(doc), system_of(doc, self.nominal), doc,
                              int(doc["report"][ONLINE_MARK].get("samples", 0)))  # fmt: skip
        except (InputError, KeyError, TypeError, ValueError) as exc:
            event(log, "resume_refused", logging.WARNING, file=str(self.out_file), error=str(exc))
            return False
        self.current = cal
        self._file_seen = self._stat()
        event(log, "calibration_resumed", version=cal.version, file=str(self.out_file))
        return True

    def surface_of(self, spot_world: Array) -> str:
        """The scene object ``spot_world`` lies on (within ``SURFACE_TOL_M``), or ""."""
        if self.scene is None or self.scene.empty:
            return ""
        dist, idx = self.scene.closest(np.asarray(spot_world, dtype=float)[None])
        return self.scene.names[int(idx[0])] if float(dist[0]) <= SURFACE_TOL_M else ""

    def add_planned(self, plan: Plan) -> int:
        """Remember the solved configurations of a plan (``solutions[].q`` of the ``ok``
        ones): a refit must keep their mirror hits in the usable area. Returns how many;
        never raises."""
        n = 0
        for sol in plan.solutions:
            if sol.status is not Status.OK or not sol.q:
                continue
            try:
                qs = make_sample(self.nominal, dict(sol.q), np.zeros(3)).q
            except InputError:
                continue
            with self._lock:
                self._planned.append(qs)
            n += 1
        return n

    @property
    def n_samples(self) -> int:
        with self._lock:
            return len(self._samples)

    # --- the refit thread ------------------------------------------------------------------
    def start(self) -> OnlineCalibrator:
        self._thread.start()
        return self

    def close(self) -> None:
        with self._lock:
            self._closing = True
            self._wake.notify()
        if self._thread.is_alive():
            self._thread.join(timeout=10)

    def wait_idle(self, timeout: float) -> bool:
        """Block until every queued sample has been through a refit attempt (tests, studies)."""
        return self._idle.wait(timeout)

    def _loop(self) -> None:
        while True:
            with self._lock:
                if not self._pending and not self._closing:
                    self._wake.wait(POLL_S)
                if self._closing:
                    return
            try:
                rolled = self.check_rollback()  # first: it drops the samples it supersedes
                with self._lock:
                    pending, self._pending = self._pending and not rolled, False
                    samples = list(self._samples)
                if pending:
                    self.refit_now(samples)
            except Exception:  # a bug must not end online calibration or touch the planner
                log.exception("online calibration: refit crashed; calibration unchanged")
            with self._lock:
                if not self._pending:
                    self._idle.set()

    def refit_now(self, samples: list[SpotSample]) -> RefitResult:
        """One refit attempt on ``samples``; on acceptance write, rebuild, install, publish."""
        kept = history(self.out_file)
        with self._lock:
            planned = list(self._planned)
        result = refit(samples, self.current, self.nominal, loss_scale=self.loss_scale,
                       planned_q=planned, first_version=max(kept, default=0) + 1)  # fmt: skip
        self.refits += 1
        self.last = result
        if not result.accepted:
            event(log, "refit_refused", **result.figures())
            return result
        cal = result.calibration
        assert cal.document is not None
        with history_lock(self.out_file):
            if self._stat() != self._file_seen or cal.version in history(self.out_file):
                # FILE or its history moved on while this refit ran (a rollback): the
                # rollback wins; it is installed next, and later samples refit from it
                event(log, "refit_dropped", logging.WARNING, version=cal.version,
                      reason="FILE changed during the refit")  # fmt: skip
                return dataclasses.replace(result, accepted=False, calibration=self.current,
                                           reason="FILE changed during the refit")  # fmt: skip
            if self.current.version not in history(self.out_file):  # for a rollback
                before = self.current.document or document_of(
                    self.current.system, self.current.version, "the calibration in force"
                    " before the first online refit")  # fmt: skip
                write_atomically(history_dir(self.out_file) / f"{self.current.version:04d}.yaml",
                                 before)  # fmt: skip
            write_atomically(history_dir(self.out_file) / f"{cal.version:04d}.yaml", cal.document)
            self._install(cal)
        event(log, "refit_accepted", **result.figures(), file=str(self.out_file))
        return result

    def _install(self, cal: Calibration) -> None:
        assert cal.document is not None
        write_atomically(self.out_file, cal.document)
        self._file_seen = self._stat()
        handler = self.rebuild(self.out_file) if self.rebuild is not None else None
        self.current = cal
        if self.on_update is not None:
            self.on_update(handler, cal)
        if self.publish is not None:
            self.publish(self.message(cal))

    def _stat(self) -> tuple[int, int] | None:
        try:
            st = self.out_file.stat()
        except OSError:
            return None
        return st.st_mtime_ns, st.st_size

    def check_rollback(self) -> bool:
        """Install a rollback written to FILE (``beamrelay calibrate rollback``) since the
        last look: a higher version marked ``rolled_back_to``. True when one was installed."""
        stat = self._stat()
        if stat is None or stat == self._file_seen:
            return False
        self._file_seen = stat
        try:
            doc = read_document(self.out_file)
            version = version_of(doc)
            to = doc["report"][ONLINE_MARK].get("rolled_back_to")
            if to is not None:
                check_poses(doc, self.out_file)
            system = system_of(doc, self.nominal) if to is not None else None
        except (InputError, KeyError, TypeError, ValueError) as exc:
            event(log, "rollback_ignored", logging.WARNING, file=str(self.out_file), error=str(exc))
            return False
        if system is None or version <= self.current.version:
            return False
        was = self.current.version
        with self._lock:
            dropped = len(self._samples)
            self._samples.clear()
        self._install(Calibration(version, system, doc, 0))
        event(log, "calibration_rolled_back", logging.WARNING, version=version, to=int(to),
              was=was, samples_dropped=dropped, file=str(self.out_file))  # fmt: skip
        return True

    def message(self, cal: Calibration) -> bytes:
        """The :class:`~schemas.messages.CalibrationMessage` body of ``cal``."""

        msg = CalibrationMessage(t=self.clock(), version=cal.version, samples=cal.samples,
                                 calibration=dict(cal.document or {}))  # fmt: skip
        return encode(msg)


def attach(
    online: OnlineCalibrator,
    session: Any,
    keys: Any,
    robots: tuple[str, ...],
    joints: Callable[[str], tuple[float, Array, Array] | None],
    install: Callable[[Any, Calibration], None],
) -> tuple[Any, list[Any]]:
    """Wire ``online`` to a node's bus and start it: it publishes on ``<prefix>/calibration``
    (the publisher returned), installs what it accepts with ``install(handler, calibration)``
    and, with :attr:`~OnlineCalibrator.rest_sampling`, takes rest samples from
    ``<prefix>/camera/spot`` (:class:`RestSampler` over ``joints``; the subscriber handles
    returned)."""

    pub = session.declare_publisher(keys.calibration)
    online.publish = lambda body: pub.put(body, encoding=JSON)
    online.on_update = install
    handles = []
    if online.rest_sampling:
        sampler = RestSampler(online, robots, joints)
        handles.append(session.declare_subscriber(keys.camera_spot, sampler.callback))
    online.start()
    return pub, handles


class RestSampler:
    """Turns ``camera/spot`` frames into samples when every robot is at rest (module docstring).

    ``joints(robot)`` returns ``(receive time, q, qd)`` or None (the node's JointCache.get).
    """

    def __init__(
        self,
        calibrator: OnlineCalibrator,
        robots: tuple[str, ...],
        joints: Callable[[str], tuple[float, Array, Array] | None],
        max_age: float = 0.1,
    ) -> None:
        self.calibrator, self.robots, self.joints = calibrator, robots, joints
        self.max_age = max_age
        self._prev: Array | None = None  # joints at the previous usable frame
        self._taken: Array | None = None  # joints of the last sample taken

    def callback(self, sample: Any) -> None:
        """Zenoh callback of ``<prefix>/camera/spot``: any body is fine (bad ones are logged)."""

        if len(sample.payload) > MAX_PAYLOAD_BYTES:
            return
        msg = decode_sample(sample, SpotMessage, log, "camera spot")
        if msg is not None:
            self.on_spot(msg.p_camera, msg.confidence)

    def on_spot(self, p_camera: Any, confidence: float) -> bool:
        """One detected spot (camera frame, m); True when it became a sample."""
        q = self._rest_q()
        if q is None or p_camera is None or not confidence >= MIN_CONFIDENCE:
            self._prev = q
            return False
        same = self._prev is not None and float(np.max(np.abs(q - self._prev))) < SAME_Q
        self._prev = q
        if not same:
            return False  # wait for a second frame at the same configuration
        if self._taken is not None and float(np.max(np.abs(q - self._taken))) < SAME_Q:
            return False  # this rest configuration has its sample already
        self._taken = q
        return self.calibrator.add_camera_spot(q, p_camera)

    def _rest_q(self) -> Array | None:
        now, parts = time.monotonic(), []
        for r in self.robots:
            entry = self.joints(r)
            if entry is None or now - entry[0] > self.max_age:
                return None
            _, q, qd = entry
            if qd.shape != q.shape or not float(np.max(np.abs(qd), initial=0.0)) < REST_QD:
                return None
            parts.append(q)
        return np.concatenate(parts)
