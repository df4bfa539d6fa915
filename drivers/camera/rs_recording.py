"""Writing RealSense ``.db3`` recordings without a device (``rs.software_device`` +
``rs.recorder``): how the tests run the real SDK path of :mod:`drivers.camera.realsense`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from planner.model.system import Intrinsics
from planner.model.transforms import Array

DEPTH_UNIT = 0.001  # m per z16 count written by write_recording


def _software_device(
    intrinsics: Intrinsics, colour: bool, fps: int
) -> tuple[Any, list[Any], list[Any], Any]:
    """A ``rs.software_device`` with a z16 depth sensor (and an rgb8 colour sensor sharing
    ``intrinsics``, identity extrinsics): (device, sensors, their profiles, rs intrinsics)."""
    import pyrealsense2 as rs

    k = rs.intrinsics()
    k.width, k.height = intrinsics.width, intrinsics.height
    k.fx, k.fy, k.ppx, k.ppy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    k.model, k.coeffs = rs.distortion.none, [0.0] * 5
    dev = rs.software_device()
    sensors, profiles = [], []
    streams = [("Depth", rs.stream.depth, rs.format.z16, 2)]
    if colour:
        streams.append(("Color", rs.stream.color, rs.format.rgb8, 3))
    for uid, (name, stream, fmt, bpp) in enumerate(streams):
        s = dev.add_sensor(name)
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.fmt, vs.bpp = stream, 0, uid, fmt, bpp
        vs.width, vs.height, vs.fps, vs.intrinsics = k.width, k.height, fps, k
        profiles.append(s.add_video_stream(vs, True))
        sensors.append(s)
    sensors[0].add_read_only_option(rs.option.depth_units, DEPTH_UNIT)
    if colour:
        ext = rs.extrinsics()
        ext.rotation, ext.translation = [1.0, 0, 0, 0, 1, 0, 0, 0, 1], [0.0, 0, 0]
        profiles[0].register_extrinsics_to(profiles[1], ext)
    return dev, sensors, profiles, k


def write_recording(
    path: Path,
    depth_m: list[Array],
    rgb: list[Array] | None,
    intrinsics: Intrinsics,
    fps: int = 30,
    t0_ms: float | None = None,
) -> None:
    """Record frames (depth in m, H x W; colour uint8 H x W x 3) to a ``.db3`` file.

    Uses ``rs.software_device`` with a depth and a colour sensor sharing ``intrinsics`` and
    identity extrinsics, and ``rs.recorder``; the result plays back like a real camera.
    ``rgb=None`` records depth only (a camera whose colour stream never arrives).
    ``t0_ms``: stamp frame ``i`` at ``t0_ms + i * 1000 / fps`` ms in the ``global_time``
    domain (host UNIX ms, as a live D400 stamps its frames), else device-clock stamps.
    """

    import pyrealsense2 as rs

    dev, sensors, profiles, k = _software_device(intrinsics, rgb is not None, fps)
    recorder = rs.recorder(str(path), dev)
    queue = rs.frame_queue(16)
    for s, p in zip(sensors, profiles, strict=True):
        s.open(p)
        s.start(queue)
    for i, d in enumerate(depth_m):
        z16 = np.where(np.isfinite(d), np.round(d / DEPTH_UNIT), 0).astype(np.uint16)
        images = [z16] if rgb is None else [z16, rgb[i]]
        for s, p, img, bpp in zip(sensors, profiles, images, (2, 3), strict=False):
            f = rs.software_video_frame()
            f.pixels = np.ascontiguousarray(img)
            f.stride, f.bpp = k.width * bpp, bpp
            f.timestamp, f.frame_number = (t0_ms or 0.0) + i * 1000.0 / fps, i
            f.domain = (
                rs.timestamp_domain.hardware_clock
                if t0_ms is None
                else rs.timestamp_domain.global_time
            )
            f.profile = p.as_video_stream_profile()
            s.on_video_frame(f)
        time.sleep(1.0 / fps)  # let the recorder drain the frames in order
    for s in sensors:
        s.stop()
        s.close()
    del recorder  # flushes and closes the file
