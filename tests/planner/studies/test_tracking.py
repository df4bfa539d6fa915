"""Tracking study: object geometry, the truth model, and the error with perfect calibration."""

from __future__ import annotations

import numpy as np
import pytest

from planner.studies import tracking as trk

ZERO = trk.CalibrationErrors(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, source="none")


def test_finger_markers_lie_on_the_cylinder() -> None:
    pts, normals, _ = trk.experiment("finger")
    axis_point = trk.CENTER + np.array([0.0, 0.0, 0.009])
    radial = (pts - axis_point)[:, 1:]
    assert np.allclose(np.linalg.norm(radial, axis=1), 0.009, atol=1e-12)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    assert np.allclose(normals[:, 1:], radial / 0.009)


def test_face_markers_on_the_mesh() -> None:
    """Casting down onto the face mesh lands on the markers (height field ↔ mesh)."""
    pts, normals, _ = trk.experiment("face")
    _, _, scene = trk._scene("face")
    for p in pts[::5]:
        t = trk._cast(scene, p + np.array([0.0, 0.0, 0.2]), np.array([0.0, 0.0, -1.0]))
        assert t == pytest.approx(0.2, abs=2e-4)
    assert np.all(normals[:, 2] > 0.5)


def test_zero_calibration_error_keeps_the_nominal_system() -> None:
    nominal = trk.nominal_system()
    truth = trk.true_system(nominal, ZERO, np.random.default_rng(0))
    assert np.allclose(truth.world_T_laser, nominal.world_T_laser)
    assert truth.camera is not None and nominal.camera is not None
    assert np.allclose(truth.camera.world_T_camera, nominal.camera.world_T_camera)


def test_calibration_error_magnitudes() -> None:
    """RMS of the drawn translation norms ≈ the requested level (1000 draws)."""
    rng = np.random.default_rng(3)
    err = np.array([np.linalg.norm(trk._rand_T(rng, 0.0, 2e-3)[:3, 3]) for _ in range(1000)])
    assert np.sqrt(np.mean(err**2)) == pytest.approx(2e-3, rel=0.08)


def test_perfect_calibration_leaves_only_camera_noise() -> None:
    """With exact geometry the chessboard error is the D435 noise of two measurements at
    z ≈ 0.85 m: depth σ_z = z²·0.08/(fx·b)/15 (15 x 15 plane fit) along the ray and
    0.05 px · z/fx across it, per measurement; the difference of two is √2 times that."""
    rows = trk.trial_rows(0, 0, ZERO, ("chessboard",))
    chess = np.array([r["error_mm"] for r in rows if r["experiment"] == "chessboard"])
    assert np.all(np.isfinite(chess))
    z, fx = 0.85, 430.0
    sigma_z = 1000 * z**2 * 0.08 / (fx * 0.05) / 15
    sigma_xy = 1000 * 0.05 * z / fx
    rms = np.sqrt(2 * (sigma_z**2 + 2 * sigma_xy**2))  # 3D RMS of the difference
    assert np.sqrt(np.mean(chess**2)) == pytest.approx(rms, rel=0.35)
