"""Targets picked in the camera's point cloud, each with the normal of a plane fitted (SVD) to
the cloud around it, as the paper picked its curve, face and finger targets in the D435's cloud.

An operator clicks the pixel where the camera shows the target; the target is that pixel's
cloud point (one frame of :meth:`drivers.camera.sim.SimCamera.points`: its depth, with the
camera's depth noise, deprojected along the pixel's ray). The pick is one of the four pixels
around the target's true image position, the one that shows the target's surface nearest to
it (:func:`pixels`): the pick's resolution is one pixel; no further human pick error is
modelled (none is published for this task). The normal
is the right singular vector with the smallest singular value of the cloud points within
:data:`NORMAL_RADIUS` of the picked point, centred on their mean, turned toward the camera
(docs/conventions.md: a normal points to the side the beam and the camera see). Camera
optical frame (x right, y down, z forward), metres, pixels.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from planner.model.system import Intrinsics
from planner.model.transforms import Array

#: m: the neighbourhood of the plane fit. The product's own pick on the cloud uses 10 mm
#: (``planner.console.picking.NORMAL_RADIUS``, README "Pick"; the paper gives no radius). At
#: the paper cell's 0.85 m one D435 depth pixel spans z / fx = 2 mm (fx 430 px), so the disc
#: is 5 pixels in radius (~80 points), about one census matching window (9 px,
#: ``planner.model.d435.CENSUS_PX``) across: it averages the pixel noise of ~80 points yet
#: stays on the finger (r = 9 mm): the table lies 16-18 mm below its markers.
NORMAL_RADIUS = 0.010
#: the experiments whose targets the paper picked in the cloud (the chessboard's corners are
#: detected, not picked)
PICKED = ("curve", "face", "finger")
#: fewest neighbours that make a plane (``planner.console.picking.MIN_NEIGHBOURS``)
MIN_NEIGHBOURS = 6


class CloudTargets(NamedTuple):
    """Picked targets (K x 3, camera frame, m) and their unit normals (K x 3, toward the
    camera); NaN rows where the pick's pixel sees nothing or the fit has too few points."""

    points: Array
    normals: Array


def organize(cloud: Array, k: Intrinsics, stride: int = 1) -> Array:
    """The unorganised cloud (M x 3, camera frame, m; one point per pixel, noise along the
    pixel's ray) back on its pixel grid: (H / stride, W / stride, 3), NaN where no point.
    A point's pixel is its projection (the depth noise moves it along its own ray)."""
    P = np.asarray(cloud, dtype=float).reshape(-1, 3)
    h, w = -(-k.height // stride), -(-k.width // stride)
    img = np.full((h, w, 3), np.nan)
    u = np.rint((k.fx * P[:, 0] / P[:, 2] + k.cx) / stride).astype(int)
    v = np.rint((k.fy * P[:, 1] / P[:, 2] + k.cy) / stride).astype(int)
    img[v, u] = P
    return img


def pixels(p_camera: Array, clean: Array, k: Intrinsics, stride: int = 1) -> tuple[Array, Array]:
    """The operator's pick of each target (K x 3, camera frame, m): of the four grid pixels
    around its sub-pixel image position, the one whose point in the noiseless organised
    cloud ``clean`` (what the aligned colour image shows there) is nearest the target, so a
    click that falls just off a grazed object's edge is nudged back onto it. Returns the
    (u, v) grid indices (int); a target none of whose four pixels sees anything gets the
    nearest pixel."""
    p = np.asarray(p_camera, dtype=float).reshape(-1, 3)
    uf = (k.fx * p[:, 0] / p[:, 2] + k.cx) / stride
    vf = (k.fy * p[:, 1] / p[:, 2] + k.cy) / stride
    h, w = clean.shape[:2]
    cu = np.clip(np.floor(uf)[:, None] + np.array([0, 1, 0, 1]), 0, w - 1).astype(int)
    cv = np.clip(np.floor(vf)[:, None] + np.array([0, 0, 1, 1]), 0, h - 1).astype(int)
    d = np.linalg.norm(clean[cv, cu] - p[:, None, :], axis=2)
    d = np.where(np.isfinite(d), d, np.inf) + 1e-12 * np.hypot(cu - uf[:, None], cv - vf[:, None])
    best = np.argmin(d, axis=1)
    rows = np.arange(len(p))
    return cu[rows, best], cv[rows, best]


def svd_normals(neighbours: Array, mask: Array) -> tuple[Array, Array]:
    """Plane normals of K point sets at once: ``neighbours`` (K x N x 3, m), ``mask`` (K x N)
    the points that belong to each set. Per set, the right singular vector of the centred
    points with the smallest singular value (unit, sign arbitrary; NaN for fewer than
    :data:`MIN_NEIGHBOURS` points) and the singular values (K x 3, m) of the centred set."""
    m = np.asarray(mask, dtype=bool)
    P = np.where(m[..., None], np.nan_to_num(np.asarray(neighbours, dtype=float)), 0.0)
    n = m.sum(axis=1)
    centre = P.sum(axis=1) / np.maximum(n, 1)[:, None]
    C = np.where(m[..., None], P - centre[:, None, :], 0.0)  # masked rows add nothing
    _, sv, Vt = np.linalg.svd(C, full_matrices=False)
    normals = Vt[:, -1, :]
    few = n < MIN_NEIGHBOURS
    normals[few], sv[few] = np.nan, np.nan
    return normals, sv


def cloud_normals(img: Array, u: Array, v: Array, centres: Array, radius: float,
                  fx: float, stride: int = 1) -> Array:  # fmt: skip
    """Normals (K x 3, toward the camera) at ``centres`` (K x 3, camera frame, m) of the
    organised cloud ``img`` (:func:`organize`): SVD of its points within ``radius`` (m) of
    each centre, searched in the pixels around (u, v) that a ball of that radius can cover
    (``radius * fx / (z - radius)`` px at depth z)."""
    c = np.asarray(centres, dtype=float).reshape(-1, 3)
    z_min = np.nanmin(c[:, 2]) if np.any(np.isfinite(c[:, 2])) else 1.0
    half = int(np.ceil(radius * fx / max(z_min - radius, 1e-3) / stride))
    du, dv = np.meshgrid(np.arange(-half, half + 1), np.arange(-half, half + 1))
    uu = np.asarray(u)[:, None] + du.ravel()[None]
    vv = np.asarray(v)[:, None] + dv.ravel()[None]
    inside = (uu >= 0) & (uu < img.shape[1]) & (vv >= 0) & (vv < img.shape[0])
    nb = img[np.clip(vv, 0, img.shape[0] - 1), np.clip(uu, 0, img.shape[1] - 1)]
    with np.errstate(invalid="ignore"):
        near = inside & (np.linalg.norm(nb - c[:, None, :], axis=2) <= radius)
    normals, _ = svd_normals(nb, near)
    flip = np.einsum("kj,kj->k", normals, -c) < 0  # the camera sits at the origin
    normals[flip] *= -1.0
    return normals


def pick_targets(cloud: Array, clean: Array, p_camera: Array, seen: NDArray[np.bool_],
                 k: Intrinsics, stride: int = 1,
                 radius: float = NORMAL_RADIUS) -> CloudTargets:  # fmt: skip
    """The targets at the true points ``p_camera`` (K x 3, camera frame, m) as an operator
    picks them in one frame's ``cloud`` (M x 3, with the depth noise; ``clean``: the same
    pixels' noiseless points): the cloud point of the pixel :func:`pixels` picks and its SVD
    normal (see the module docstring). ``seen`` (K, bool): the targets the camera sees (the
    others stay NaN)."""
    p = np.asarray(p_camera, dtype=float).reshape(-1, 3)
    out_p, out_n = np.full(p.shape, np.nan), np.full(p.shape, np.nan)
    idx = np.flatnonzero(np.asarray(seen, dtype=bool))
    if len(idx) == 0:
        return CloudTargets(out_p, out_n)
    img = organize(cloud, k, stride)
    u, v = pixels(p[idx], organize(clean, k, stride), k, stride)
    picked = img[v, u]
    out_p[idx] = picked
    out_n[idx] = cloud_normals(img, u, v, picked, radius, k.fx, stride)
    bad = ~np.all(np.isfinite(out_n), axis=1)
    out_p[bad], out_n[bad] = np.nan, np.nan
    return CloudTargets(out_p, out_n)
