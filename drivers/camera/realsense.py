"""Intel RealSense camera (backend ``realsense``) through pyrealsense2.

Per frame: ``pipeline.wait_for_frames()`` (blocks at the device rate), depth aligned to the
colour stream (``rs.align(color)``), so both share the colour camera's optical frame and
intrinsics (the frame the scenario's ``world_T_camera`` must describe: OpenCV x right,
y down, z forward, metres).

- Cloud: ``rs.pointcloud`` of the aligned depth, textured by the colour frame: rows
  ``x, y, z, r, g, b`` (m; colour in [0, 1]), pixels without depth dropped.
- Spot: the brightest red blob: redness ``R - max(G, B)``; pixels above
  ``max(RED_MIN, RED_FRACTION x peak)`` that are connected to the peak form the blob; its
  redness-weighted centroid (u, v) is deprojected (``rs2_deproject_pixel_to_point``) with the
  median of the valid depths in a ``SPOT_WINDOW`` x ``SPOT_WINDOW`` window around it (the
  spot itself often saturates the IR pattern and has no depth). Confidence = peak redness /
  255 x fraction of the window with depth. No blob above ``RED_MIN`` -> no spot.

Without hardware: :func:`write_recording` writes a ``.db3`` recording through
``rs.software_device`` + ``rs.recorder``; ``RealSenseCamera(file=...)`` plays it back with
``config.enable_device_from_file`` (this is how the tests run the real SDK path).
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import numpy as np

from drivers.camera.node import SpotReading
from planner.errors import InputError
from planner.model.system import Intrinsics
from planner.model.transforms import Array

RED_MIN = 60  # minimum redness R - max(G, B) of a spot pixel (0..255)
RED_FRACTION = 0.5  # blob = pixels above this fraction of the peak redness
SPOT_WINDOW = 15  # px, window whose median depth is the spot depth
DEPTH_UNIT = 0.001  # m per z16 count written by write_recording


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
    ) -> None:
        import pyrealsense2 as rs

        self.rs = rs
        self.timeout_ms = timeout_ms
        self.pipeline = rs.pipeline()
        config = rs.config()
        if file is not None:
            config.enable_device_from_file(str(file), repeat_playback=True)
        else:
            if serial:
                config.enable_device(serial)
            config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
            config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        try:
            profile = self.pipeline.start(config)
        except RuntimeError as exc:  # no device, busy device, unreadable file
            where = f"--file {file}" if file is not None else f"--serial {serial or '(any)'}"
            raise InputError(f"cannot start the RealSense pipeline: {exc}", where) from exc
        if file is not None:
            profile.get_device().as_playback().set_real_time(realtime)
        self.align = rs.align(rs.stream.color)
        self.pc = rs.pointcloud()
        self._depth: Any = None
        self._color: Any = None

    def on_joint_state(self, robot: str, q: Array) -> None:
        """Not used: the real camera sees the real beam."""

    def grab(self) -> None:
        """Wait for the next frameset and align its depth to colour."""
        frames = self.pipeline.wait_for_frames(self.timeout_ms)
        aligned = self.align.process(frames)
        self._depth = aligned.get_depth_frame()
        self._color = aligned.get_color_frame()

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

    def spot(self) -> SpotReading | None:
        """Brightest red blob of the last frame, deprojected (camera frame, m), or None."""
        rgb = np.asanyarray(self._color.get_data())
        depth_m = np.asanyarray(self._depth.get_data()) * self._depth.get_units()
        found = detect_red_spot(rgb)
        if found is None:
            return None
        (u, v), peak = found
        r = SPOT_WINDOW // 2
        win = depth_m[max(0, int(v) - r) : int(v) + r + 1, max(0, int(u) - r) : int(u) + r + 1]
        valid = win[win > 0]
        if valid.size == 0:
            return None
        z = float(np.median(valid))
        k = self._color.get_profile().as_video_stream_profile().get_intrinsics()
        # librealsense pixel coordinates: integer = pixel centre, as for OpenCV
        p = np.array(self.rs.rs2_deproject_pixel_to_point(k, [float(u), float(v)], z))
        return SpotReading(p, float(peak / 255.0 * valid.size / win.size))

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):  # already stopped
            self.pipeline.stop()


def detect_red_spot(rgb: Array) -> tuple[tuple[float, float], float] | None:
    """Centroid (u, v) in px of the brightest red blob and its peak redness, or None."""
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


def write_recording(
    path: Path,
    depth_m: list[Array],
    rgb: list[Array],
    intrinsics: Intrinsics,
    fps: int = 30,
) -> None:
    """Record frames (depth in m, H x W; colour uint8 H x W x 3) to a ``.db3`` file.

    Uses ``rs.software_device`` with a depth and a colour sensor sharing ``intrinsics`` and
    identity extrinsics, and ``rs.recorder``; the result plays back like a real camera.
    """
    import time

    import pyrealsense2 as rs

    k = rs.intrinsics()
    k.width, k.height = intrinsics.width, intrinsics.height
    k.fx, k.fy, k.ppx, k.ppy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    k.model, k.coeffs = rs.distortion.none, [0.0] * 5
    dev = rs.software_device()
    sensors, profiles = [], []
    for uid, (name, stream, fmt, bpp) in enumerate(
        [
            ("Depth", rs.stream.depth, rs.format.z16, 2),
            ("Color", rs.stream.color, rs.format.rgb8, 3),
        ]
    ):
        s = dev.add_sensor(name)
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.fmt, vs.bpp = stream, 0, uid, fmt, bpp
        vs.width, vs.height, vs.fps, vs.intrinsics = k.width, k.height, fps, k
        profiles.append(s.add_video_stream(vs, True))
        sensors.append(s)
    sensors[0].add_read_only_option(rs.option.depth_units, DEPTH_UNIT)
    ext = rs.extrinsics()
    ext.rotation, ext.translation = [1.0, 0, 0, 0, 1, 0, 0, 0, 1], [0.0, 0, 0]
    profiles[0].register_extrinsics_to(profiles[1], ext)
    recorder = rs.recorder(str(path), dev)
    queue = rs.frame_queue(16)
    for s, p in zip(sensors, profiles, strict=True):
        s.open(p)
        s.start(queue)
    for i, (d, c) in enumerate(zip(depth_m, rgb, strict=True)):
        z16 = np.where(np.isfinite(d), np.round(d / DEPTH_UNIT), 0).astype(np.uint16)
        for s, p, img, bpp in ((sensors[0], profiles[0], z16, 2), (sensors[1], profiles[1], c, 3)):
            f = rs.software_video_frame()
            f.pixels = np.ascontiguousarray(img)
            f.stride, f.bpp = k.width * bpp, bpp
            f.timestamp, f.frame_number = i * 1000.0 / fps, i
            f.domain = rs.timestamp_domain.hardware_clock
            f.profile = p.as_video_stream_profile()
            s.on_video_frame(f)
        time.sleep(1.0 / fps)  # let the recorder drain the frames in order
    for s in sensors:
        s.stop()
        s.close()
    del recorder  # flushes and closes the file
