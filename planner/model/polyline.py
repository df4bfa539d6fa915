"""Polylines of path samples: arc length, the one resampler, runs of good samples.

Points are (K, 3) arrays in any one frame, lengths in metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.model.transforms import Array


def arc_length(points: Array, closed: bool = False) -> Array:
    """Cumulative arc length (m) of a polyline's vertices, starting at 0."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


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


def resample_polyline(points: Array, spacing: float, closed: bool = False,
                      normals: Array | None = None) -> tuple[Array, Array | None]:  # fmt: skip
    """:func:`resample_path` at the spacing nearest ``spacing`` (m) that divides the
    polyline's length exactly; a closed path does not repeat its start."""
    P = np.asarray(points, dtype=float)
    length = float(arc_length(np.vstack([P, P[:1]]) if closed else P)[-1])
    n = max(1, int(np.ceil(length / spacing - 1e-9)))
    out, nrm = resample_path(P, spacing=length / n, normals=normals, closed=closed)
    if closed and len(out) > 1:
        out, nrm = out[:-1], None if nrm is None else nrm[:-1]
    return out, nrm


def runs(mask: Array, offset: int = 0) -> list[tuple[int, int]]:
    """Half-open index ranges ``[k0, k1)`` (plus ``offset``) of consecutive True values."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(mask).astype(int), [0]])))
    edges = edges + offset
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
