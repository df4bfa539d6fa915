"""Marked strokes of a path: sharp corners split it, small turns are blended within the
tolerance, smooth curves are splined; and the scenario keys behind them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError
from planner.io.strokes import BLEND_SHARE, CHORD_SHARE, mark_path, turn_angles
from tests import cli_run

TOL = 5e-5


def _polyline_distance(X: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Distance of points X (M x 3) to the polyline V (independent of the module)."""
    a, b = V[:-1], V[1:]
    ab = b - a
    u = np.clip(np.einsum("mkj,kj->mk", X[:, None] - a, ab) / (ab * ab).sum(1), 0, 1)
    return np.linalg.norm(X[:, None] - (a + u[..., None] * ab), axis=2).min(axis=1)


def _bend(theta_deg: float, length: float = 0.01) -> np.ndarray:
    """Two edges of ``length`` m meeting at the origin with a turn of theta."""
    th = np.radians(theta_deg)
    return np.array([[-length, 0, 0], [0, 0, 0], [length * np.cos(th), length * np.sin(th), 0]])


def test_turn_angles_known_values() -> None:
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [2, 2, 0], [3, 2, 0.0]])
    np.testing.assert_allclose(np.degrees(turn_angles(V)), [90, 45, 45], atol=1e-12)
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    np.testing.assert_allclose(np.degrees(turn_angles(sq, closed=True)), [90] * 4, atol=1e-12)


def test_closed_square_is_four_sharp_strokes() -> None:
    sq = np.array([[-0.57, 0.23, 0], [-0.53, 0.23, 0], [-0.53, 0.27, 0], [-0.57, 0.27, 0]])
    m = mark_path(sq, 0.002, closed=True)
    assert m.sharp == 4 and m.blended == 0 and len(m.strokes) == 4
    assert len(m.points) == 80  # 4 x 40 mm at 2 mm, the start not repeated
    for k, stroke in enumerate(m.strokes):
        # each stroke runs from one vertex to the next, both sampled exactly
        np.testing.assert_allclose(m.points[stroke[0]], sq[k], atol=1e-15)
        np.testing.assert_allclose(m.points[stroke[-1]], sq[(k + 1) % 4], atol=1e-15)
        assert len(stroke) == 21
    assert m.strokes[-1][-1] == 0  # the loop ends on the first sample
    assert _polyline_distance(m.points, np.vstack([sq, sq[:1]])).max() < 1e-15


@pytest.mark.parametrize("theta", [3.0, 12.0, 19.9])
def test_a_small_turn_is_blended_within_the_tolerance(theta: float) -> None:
    V = _bend(theta)
    m = mark_path(V, 0.001, tolerance=TOL)
    assert len(m.strokes) == 1 and m.sharp == 0 and m.blended == 1
    dist = _polyline_distance(m.points, V)
    mids = _polyline_distance(0.5 * (m.points[1:] + m.points[:-1]), V)
    th = np.radians(theta)
    # the blend arc: radius from the share of the tolerance (or half the edge), its apex
    # cuts the corner by r (1 - cos(theta/2)), which is where the samples are farthest
    r = min(BLEND_SHARE * TOL / (1 - np.cos(th / 2)), 0.005 / np.tan(th / 2))
    cut = r * (1 - np.cos(th / 2))
    assert cut <= BLEND_SHARE * TOL * (1 + 1e-12)
    assert dist.max() == pytest.approx(cut, rel=1e-3)
    # a chord between samples sags at most the chord share below the arc
    assert mids.max() <= cut + CHORD_SHARE * TOL + 1e-12
    steps = np.linalg.norm(np.diff(m.points, axis=0), axis=1)
    assert steps.max() <= 0.001 + 1e-15
    np.testing.assert_allclose(m.points[[0, -1]], V[[0, -1]], atol=1e-15)


def test_corner_deg_decides_sharp_or_swept() -> None:
    V = _bend(25.0)
    sharp = mark_path(V, 0.001, corner_deg=20.0)
    assert sharp.sharp == 1 and len(sharp.strokes) == 2
    a, b = sharp.strokes
    assert a[-1] == b[0]  # the strokes share the vertex sample
    np.testing.assert_allclose(sharp.points[a[-1]], [0, 0, 0], atol=1e-15)
    assert _polyline_distance(sharp.points, V).max() < 1e-15
    swept = mark_path(V, 0.001, corner_deg=30.0)
    assert swept.sharp == 0 and swept.blended == 1 and len(swept.strokes) == 1
    assert _polyline_distance(swept.points, V).max() <= BLEND_SHARE * TOL * (1 + 1e-12)


def test_normals_follow_the_polyline() -> None:
    V = _bend(10.0)
    N = np.array([[0, 0, 1.0], [0, 1, 1.0], [0, 1, 0.0]])
    m = mark_path(V, 0.001, normals=N)
    assert m.normals is not None
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(m.normals[0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(m.normals[-1], [0, 1, 0], atol=1e-12)
    with pytest.raises(InputError, match="opposite") as bad:
        mark_path(V, 0.001, normals=[[0, 0, 1], [0, 0, -1], [0, 0, 1]])
    assert bad.value.where == "normals"  # the field, not text to parse
    with pytest.raises(InputError, match="zero length") as bad:
        mark_path([[0, 0, 0], [0, 0, 0]], 0.001)
    assert bad.value.where == "points"


def test_smooth_circle_is_one_stroke_on_the_circle() -> None:
    r = 0.015
    a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ring = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros_like(a)])
    m = mark_path(ring, 0.001, closed=True, smooth=True)
    assert len(m.strokes) == 1 and m.sharp == 0
    assert m.strokes[0][0] == 0 and m.strokes[0][-1] == 0 and len(m.strokes[0]) == len(m.points) + 1
    radial = np.linalg.norm(m.points[:, :2], axis=1)
    assert np.abs(radial - r).max() < 2e-6  # a periodic cubic spline through 24 points
    steps = np.linalg.norm(np.diff(np.vstack([m.points, m.points[:1]]), axis=0), axis=1)
    assert steps.max() <= 0.001 and steps.max() - steps.min() < 1e-6
    # read as a polyline, the same points would be 24 sharp 15 deg turns... swept, blended
    poly = mark_path(ring, 0.001, closed=True)
    assert poly.blended == 24 and poly.sharp == 0


def beamrelay(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip


BASE = """\
system:
  laser:
    world_T_laser: {xyz: [-0.491899, 0.188094, 0.074878], rpy_deg: [40, 0, 0]}
    LASER
  robots:
    - name: arm0
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075]}
targets:
  ORDER
  path: {points: [[-0.52, -0.57, -0.06], [-0.50, -0.57, -0.06]], PATH}
trajectory: {spot_speed: 0.02, TRAJ}
"""


def _scenario(tmp_path: Path, laser: str = "", order: str = "", path: str = "spacing: 0.001",
              traj: str = "rate: 500") -> Path:  # fmt: skip
    text = BASE.replace("LASER", laser).replace("ORDER", order).replace("PATH", path)
    f = tmp_path / "s.yaml"
    f.write_text(text.replace("TRAJ", traj))
    return f


def test_marking_keys_are_accepted(tmp_path: Path) -> None:
    f = _scenario(
        tmp_path,
        "power: 0.005\n    gate: {robot: arm0, output: 3}",
        "order: optimal",
        "corner_deg: 30, smooth: true",
        "path_tolerance: 1.0e-4, order: given",
    )
    out = beamrelay("validate", f)
    assert out.returncode == 0, out.stdout + out.stderr
    for order in ("optimized", "given"):  # the old spelling stays an alias
        assert beamrelay("validate", _scenario(tmp_path, order=f"order: {order}")).returncode == 0


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"laser": "power: -1"}, "power"),
        ({"laser": "power: 5000"}, "power"),
        ({"laser": "gate: {robot: arm9}"}, "arm9"),
        ({"laser": "gate: {robot: arm0, output: 8}"}, "output"),
        ({"laser": "gate: {robot: arm0, outptu: 1}"}, "outptu"),
        ({"order": "order: optimised"}, "order"),
        ({"path": "corner_deg: 200"}, "corner_deg"),
        ({"path": "corner_deg: 0"}, "corner_deg"),
        ({"path": "smooth: yes please"}, "smooth"),
        ({"path": "cornerdeg: 20"}, "cornerdeg"),
        ({"traj": "path_tolerance: 0.05"}, "path_tolerance"),  # mm given as m
        ({"traj": "path_tolerance: .nan"}, "path_tolerance"),
        ({"traj": "path_tolerance: -1e-5"}, "path_tolerance"),
        ({"traj": "order: fastest"}, "order"),
    ],
)
def test_bad_marking_keys_are_one_line_errors(tmp_path: Path, kw: dict[str, str], needle: str
                                              ) -> None:  # fmt: skip
    cli_run.assert_usage_error(cli_run.beamrelay("validate", _scenario(tmp_path, **kw)), needle)
