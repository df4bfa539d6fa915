"""Intel RealSense camera (backend ``realsense``) through pyrealsense2.

Per frame (:meth:`RealSenseCamera.grab`): ``pipeline.try_wait_for_frames`` (blocks at the
device rate), depth aligned to the colour stream (``rs.align(color)``), so both share the
colour camera's optical frame and intrinsics (the frame the scenario's ``world_T_camera``
must describe: OpenCV x right, y down, z forward, metres).

Robustness, as the SDK examples do it: a frameset without depth or colour is skipped (no
message); a timeout restarts the pipeline (up to ``reconnects`` times in a row, e.g. after
a USB reset); no complete frameset for ``3 x timeout`` or too many failed restarts raises
:class:`CameraLostError`, which ends the node's loop and the process with a non-zero
status.

Time: :meth:`RealSenseCamera.frame_time` is the colour frame's own timestamp when the SDK
gives it on the host clock (``global_time`` or ``system_time`` domain: ms since the UNIX
epoch, the time of capture), else the host time the frameset arrived; messages carry it.

- Cloud: ``rs.pointcloud`` of the aligned depth, textured by the colour frame: rows
  ``x, y, z, r, g, b`` (m; colour in [0, 1]), pixels without depth dropped.
- Spot: with laser-gate information (:meth:`RealSenseCamera.on_gate`), the gated difference
  of :mod:`drivers.camera.spot` (frames taken while the gate was on minus frames taken while
  it was off, near the predicted pixel given by :meth:`RealSenseCamera.on_predicted`).
  Without any gate information, the old single-frame detector (:func:`detect_red_spot`,
  brightest red blob; confidence halved: it cannot tell a red object from the spot). The
  spot pixel is deprojected (``rs2_deproject_pixel_to_point``) with the median of the valid
  depths in a ``SPOT_WINDOW`` x ``SPOT_WINDOW`` window (the spot often saturates the IR
  pattern and has no depth); the confidence is scaled by the window's valid fraction.
- Live devices get manual colour exposure (``exposure_us``, ``gain``): the on/off
  difference needs frames whose exposure the spot does not change.
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from drivers.camera.markers import CharucoSpec, detect_charuco
from drivers.camera.node import SpotReading
from drivers.camera.rs_recording import DEPTH_UNIT as DEPTH_UNIT
from drivers.camera.rs_recording import write_recording as write_recording
from drivers.camera.spot import PREDICTION_TTL as PREDICTION_TTL
from drivers.camera.spot import GateHistory, SpotParams, detect_gated_spot, project
from planner.errors import InputError
from planner.model.system import Intrinsics
from planner.model.transforms import Array

RED_MIN = 60  # minimum redness R - max(G, B) of a spot pixel (0..255), ungated detector
RED_FRACTION = 0.5  # blob = pixels above this fraction of the peak redness
SPOT_WINDOW = 15  # px, window whose median depth is the spot depth
HISTORY = 8  # frames kept for the gated difference


class CameraLostError(RuntimeError):
    """The camera stopped delivering complete framesets (with the evidence)."""


class RealSenseCamera:
    """Camera source for :class:`drivers.camera.node.CameraNode` (see module docstring)."""

    kind = "realsense"
    robot_names: tuple[str, ...] = ()

    def __init__(
        self,
        serial: str | None = None,
        file: Path | None = None,
        *,
        width: int = 848,
        height: int = 480,
        fps: int = 30,
        realtime: bool = True,
        timeout_ms: int = 5000,
        reconnects: int = 3,
        exposure_us: float | None = 150.0,
        gain: float | None = 16.0,
        params: SpotParams | None = None,
        record_to: Path | None = None,
    ) -> None:
        import pyrealsense2 as rs

        self.rs, self.file, self.realtime = rs, file, realtime
        self.timeout_ms, self.reconnects, self.fps = timeout_ms, reconnects, fps
        self.params = params or SpotParams()
        self.config = rs.config()
        if file is not None:
            self.config.enable_device_from_file(str(file), repeat_playback=True)
        else:
            if serial:
                self.config.enable_device(serial)
            self.config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
            self.config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
            if record_to is not None:  # the SDK writes every frame to a .db3 as it streams
                self.config.enable_record_to_file(str(record_to))
        self.where = f"--file {file}" if file is not None else f"--serial {serial or '(any)'}"
        self.pipeline = rs.pipeline()
        self._start()
        if file is None:
            self._manual_exposure(exposure_us, gain)
        self.align = rs.align(rs.stream.color)
        self.pc = rs.pointcloud()
        self._depth: Any = None
        self._color: Any = None
        self._t = 0.0
        self.timeouts = self.incomplete = self.restarts = 0
        self._failed_restarts = 0
        self._last_complete = time.monotonic()
        self.gate = GateHistory()
        self.frames: deque[tuple[float, bool | None, Array]] = deque(maxlen=HISTORY)
        self._predicted: tuple[Array, float] | None = None

    def _start(self) -> None:
        try:
            profile = self.pipeline.start(self.config)
        except RuntimeError as exc:  # no device, busy device, unreadable file
            raise InputError(f"cannot start the RealSense pipeline: {exc}", self.where) from exc
        if self.file is not None:
            profile.get_device().as_playback().set_real_time(self.realtime)

    def _manual_exposure(self, exposure_us: float | None, gain: float | None) -> None:
        """Fix the colour exposure (µs) and gain, so the laser does not change them."""
        if exposure_us is None:
            return
        sensor = self.pipeline.get_active_profile().get_device().first_color_sensor()
        sensor.set_option(self.rs.option.enable_auto_exposure, 0)
        sensor.set_option(self.rs.option.exposure, float(exposure_us))
        if gain is not None:
            sensor.set_option(self.rs.option.gain, float(gain))

    # -- inputs from the bus ------------------------------------------------------------
    def on_joint_state(self, robot: str, q: Array, t: float | None = None) -> None:
        """Not used: the real camera sees the real beam."""

    def on_gate(self, on: bool, t: float) -> None:
        """The laser gate switched (UNIX s)."""
        self.gate.record(bool(on), float(t))

    def on_predicted(self, p_camera: Array, t: float) -> None:
        """The planner's predicted spot (camera optical frame, m) at UNIX time ``t``."""
        self._predicted = (np.asarray(p_camera, dtype=float), float(t))

    # -- frames ------------------------------------------------------------------------------
    def grab(self) -> bool:
        """Wait for the next frameset; False when it was incomplete or timed out (skip it)."""
        ok, frames = self.pipeline.try_wait_for_frames(self.timeout_ms)
        if not ok:
            self.timeouts += 1
            self._restart(f"no frameset within {self.timeout_ms} ms")
            return False
        host_t = time.time()
        aligned = self.align.process(frames)
        depth, color = aligned.get_depth_frame(), aligned.get_color_frame()
        if not depth or not color:
            self.incomplete += 1
            silent = time.monotonic() - self._last_complete
            if silent > 3e-3 * self.timeout_ms:
                raise CameraLostError(
                    f"no complete frameset (depth and colour) for {silent:.1f} s "
                    f"({self.incomplete} incomplete, {self.timeouts} timeouts) from {self.where}"
                )
            return False
        self._depth, self._color = depth, color
        self._last_complete, self._failed_restarts = time.monotonic(), 0
        self._t = self._stamp(color, host_t)
        state = self.gate.state(self._t - 1.0 / self.fps, self._t + 0.005)
        self.frames.append((self._t, state, np.asanyarray(color.get_data()).copy()))
        return True

    def _stamp(self, frame: Any, host_t: float) -> float:
        domain = frame.get_frame_timestamp_domain()
        on_host = (self.rs.timestamp_domain.global_time, self.rs.timestamp_domain.system_time)
        return frame.get_timestamp() / 1e3 if domain in on_host else host_t

    def _restart(self, why: str) -> None:
        if self._failed_restarts >= self.reconnects:
            raise CameraLostError(
                f"{why}; {self.reconnects} pipeline restarts did not help ({self.where})"
            )
        self._failed_restarts += 1
        self.restarts += 1
        with contextlib.suppress(RuntimeError):
            self.pipeline.stop()
        try:
            self._start()
        except InputError as exc:
            raise CameraLostError(f"{why}; restart failed: {exc}") from exc

    def frame_time(self) -> float:
        """UNIX time (s) of the last complete frameset (see the module docstring)."""
        return self._t

    def points(self) -> tuple[Any, dict[str, Any]]:
        """Textured cloud of the last frame: (M x 6 float32: x, y, z, r, g, b)."""
        self.pc.map_to(self._color)
        cloud = self.pc.calculate(self._depth)
        xyz = np.asanyarray(cloud.get_vertices()).view(np.float32).reshape(-1, 3)
        tex = np.asanyarray(cloud.get_texture_coordinates()).view(np.float32).reshape(-1, 2)
        rgb_img = np.asanyarray(self._color.get_data())
        h, w = rgb_img.shape[:2]
        ok = xyz[:, 2] > 0
        u = np.clip((tex[ok, 0] * w).astype(int), 0, w - 1)
        v = np.clip((tex[ok, 1] * h).astype(int), 0, h - 1)
        rgb = rgb_img[v, u].astype(np.float32) / 255.0
        k = self.intrinsics()
        meta = {"width": k.width, "height": k.height, "stride": 1, "organized": False}
        return np.hstack([xyz[ok], rgb]), meta

    def intrinsics(self) -> Intrinsics:
        """Colour-camera intrinsics (the aligned frame's)."""
        k = self._color.get_profile().as_video_stream_profile().get_intrinsics()
        return Intrinsics(k.width, k.height, k.fx, k.fy, k.ppx, k.ppy)

    # -- spot ----------------------------------------------------------------------------
    def spot(self) -> SpotReading | None:
        """The laser spot of the latest frames, deprojected (camera frame, m), or None."""
        found = self._find()
        if found is None:
            return None
        (u, v), confidence = found
        depth_m = np.asanyarray(self._depth.get_data()) * self._depth.get_units()
        r = SPOT_WINDOW // 2
        win = depth_m[max(0, int(v) - r) : int(v) + r + 1, max(0, int(u) - r) : int(u) + r + 1]
        valid = win[win > 0]
        if valid.size == 0:
            return None
        z = float(np.median(valid))
        k = self._color.get_profile().as_video_stream_profile().get_intrinsics()
        # librealsense pixel coordinates: integer = pixel centre, as for OpenCV
        p = np.array(self.rs.rs2_deproject_pixel_to_point(k, [float(u), float(v)], z))
        return SpotReading(p, float(confidence * valid.size / win.size))

    def _find(self) -> tuple[tuple[float, float], float] | None:
        if not self.gate.events:  # no gate information at all: the ungated detector
            found = detect_red_spot(np.asanyarray(self._color.get_data()))
            return None if found is None else (found[0], 0.5 * found[1] / 255.0)
        on = [img for _, s, img in self.frames if s is True][-3:]
        off = [img for _, s, img in self.frames if s is False][-3:]
        if not on or not off or self.frames[-1][1] is not True:
            return None  # the laser is off now, or no reference frame to subtract
        det = detect_gated_spot(on, off, self._predicted_uv(), self.params)
        return None if det is None else ((det.u, det.v), det.confidence)

    def _predicted_uv(self) -> tuple[float, float] | None:
        if self._predicted is None or self._t - self._predicted[1] > PREDICTION_TTL:
            return None
        k = self.intrinsics()
        try:
            return project(self._predicted[0], k.fx, k.fy, k.cx, k.cy)
        except ValueError:
            return None

    def markers(self, request: dict[str, Any]) -> Array:
        """ChArUco corners of the last frame (camera frame, m; NaN = not seen); the request's
        ``charuco`` gives the board (:class:`drivers.camera.markers.CharucoSpec` fields)."""

        spec = CharucoSpec(**request.get("charuco", {}))
        depth_m = np.asanyarray(self._depth.get_data()) * self._depth.get_units()
        return detect_charuco(np.asanyarray(self._color.get_data()), depth_m,
                              self.intrinsics(), spec)  # fmt: skip

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):  # already stopped
            self.pipeline.stop()


def detect_red_spot(rgb: Array) -> tuple[tuple[float, float], float] | None:
    """Ungated: centroid (u, v) in px of the brightest red blob and its peak redness, or
    None. Any red object can win (see :mod:`drivers.camera.spot` for the gated detector)."""
    from scipy import ndimage

    img = np.asarray(rgb, dtype=np.int16)
    red = img[..., 0] - np.maximum(img[..., 1], img[..., 2])
    peak = int(red.max())
    if peak < RED_MIN:
        return None
    labels, _ = ndimage.label(red >= max(RED_MIN, RED_FRACTION * peak))
    v0, u0 = np.unravel_index(int(np.argmax(red)), red.shape)
    blob = labels == labels[v0, u0]
    weight = red * blob
    vs, us = np.nonzero(blob)
    wsum = float(weight[vs, us].sum())
    return (
        float((us * weight[vs, us]).sum() / wsum),
        float((vs * weight[vs, us]).sum() / wsum),
    ), peak
