"""Calibration output: residual statistics, uncertainties, gauge, and the includable YAML.

The file (docs/conventions.md) is a partial ``system:`` mapping with the scenario's own keys,
which a scenario pulls in with ``include:``, plus a ``report:`` mapping. Every number in
it is SI (metres, radians); only printed summaries use mm / deg, labelled.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError
from ruamel.yaml import YAML

from planner.calibration.beam import BeamResult
from planner.calibration.handeye import HandEyeResult
from planner.errors import InputError
from planner.model.transforms import Array, matrix_to_quat
from schemas.calibration import CalibrationFile

PAPER_HANDEYE_MM = (1.13, 0.50)
PAPER_BEAM_MM = (2.04, 1.25)


def residual_stats(norms: Array) -> dict[str, float | int]:
    """Mean, standard deviation, max (metres) and count of residual norms (NaN ignored)."""
    x = np.asarray(norms, dtype=float)
    x = x[np.isfinite(x)]
    return {
        "mean": float(x.mean()),
        "std": float(x.std()),
        "max": float(x.max()),
        "n": int(x.size),
    }


def spot_rms(norms: Array) -> float:
    """RMS (m) of spot residual norms (NaN ignored): the beam calibration's reported spot
    uncertainty (``report.spot_uncertainty``; safety margins use 3 x it)."""
    x = np.asarray(norms, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else 0.0


def pose_dict(T: Array) -> dict[str, list[float]]:
    """A pose as ``{xyz, quat}`` (quat ``[x, y, z, w]``) at full float precision."""
    return {
        "xyz": [float(x) for x in T[:3, 3]],
        "quat": [float(x) for x in matrix_to_quat(T[:3, :3])],
    }


def _vec(x: Array) -> list[float]:
    return [float(v) for v in np.asarray(x).ravel()]


def handeye_document(result: HandEyeResult, robot: str, dataset: str = "") -> dict[str, Any]:
    """The calibration file mapping of a hand-eye result.

    eye_to_hand writes ``system.camera.world_T_camera``; eye_in_hand writes
    ``system.camera: {robot, flange_T_camera}`` (the camera on that robot's flange).
    """
    system: dict[str, Any] = {"camera": {"world_T_camera": pose_dict(result.camera_pose)}}
    if result.mode == "eye_in_hand":
        system["camera"] = {"robot": robot, "flange_T_camera": pose_dict(result.camera_pose)}
    sd = result.std
    report: dict[str, Any] = {
        "kind": "handeye",
        "mode": result.mode,
        "robot": robot,
        "dataset": dataset,
        "calibrated": {result.camera_key: pose_dict(result.camera_pose)},
        "residuals": residual_stats(result.point_residuals)
        | {
            "per_sample_rms": [
                float(x) if np.isfinite(x) else None for x in result.sample_residuals
            ]
        },
        "auxiliary": {result.board_key: pose_dict(result.board_pose)},
        "std": {
            result.camera_key: {
                "rotation_rad": _vec(sd["camera_rotation"]),
                "translation_m": _vec(sd["camera_translation"]),
                "frame": "camera (local axes)",
            },
            result.board_key: {
                "rotation_rad": _vec(sd["board_rotation"]),
                "translation_m": _vec(sd["board_translation"]),
                "frame": "board (local axes)",
            },
        },
        "unobservable": [],
        "warnings": list(result.warnings),
        "solver": {"iterations": result.iterations, "converged": result.converged},
        "paper_mm": {"mean": PAPER_HANDEYE_MM[0], "std": PAPER_HANDEYE_MM[1]},
    }
    return {"system": system, "report": report}


def beam_document(result: BeamResult, dataset: str = "") -> dict[str, Any]:
    """The calibration file mapping of a laser-line + mirror-plane result."""
    system: dict[str, Any] = {
        "robots": [
            {"name": result.robot, "mirror": {"flange_T_mirror": pose_dict(result.flange_T_mirror)}}
        ]
    }
    calibrated: dict[str, Any] = {}
    if result.world_T_laser is not None:
        system["laser"] = {"world_T_laser": pose_dict(result.world_T_laser)}
        L = result.world_T_laser
        calibrated["laser_line"] = {
            "direction": _vec(L[:3, 2]),
            "point": _vec(L[:3, 3]),
            "frame": "world",
        }
    M = result.flange_T_mirror
    n = M[:3, 2]
    calibrated["mirror_plane"] = {
        "normal": _vec(n),
        "offset_m": float(n @ M[:3, 3]),
        "frame": f"{result.robot} flange (plane: normal . x = offset)",
    }
    report: dict[str, Any] = {
        "kind": "beam",
        "robot": result.robot,
        "dataset": dataset,
        "calibrated": calibrated,
        "residuals": residual_stats(result.residuals) | {"per_sample": _vec(result.residuals)},
        "spot_uncertainty": spot_rms(result.residuals),
        "std": {k: float(v) for k, v in result.std.items()},
        "std_units": "rx/ry in rad, t* in m; laser in laser axes, mirror in mirror axes",
        "unobservable": list(result.unobservable),
        "detected_null_space": list(result.detected),
        "singular_values": _vec(result.singular_values),
        "warnings": list(result.warnings),
        "solver": {"iterations": result.iterations, "converged": result.converged},
        "paper_mm": {"mean": PAPER_BEAM_MM[0], "std": PAPER_BEAM_MM[1]},
    }
    return {"system": system, "report": report}


def write_calibration(path: Path, document: dict[str, Any]) -> None:
    """Validate ``document`` against ``schemas.calibration.CalibrationFile`` and write YAML."""

    try:
        CalibrationFile.model_validate(document)
    except ValidationError as exc:  # our own output: a bug, but say what is wrong
        raise InputError(f"calibration output does not validate: {exc.errors()[0]}") from exc
    yaml = YAML(typ="safe", pure=True)
    yaml.default_flow_style = None
    yaml.width = 200
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as fh:
        fh.write("# beamrelay calibration: include it from a scenario (include: [this file])\n")
        yaml.dump(document, fh)


def summary_lines(document: dict[str, Any]) -> list[str]:
    """Human summary of a calibration document (mm / deg, labelled)."""
    rep = document["report"]
    res = rep["residuals"]
    paper = rep["paper_mm"]
    lines = [
        f"{rep['kind']} calibration ({rep.get('mode', rep['robot'])}): residual"
        f" {1e3 * res['mean']:.3f} ± {1e3 * res['std']:.3f} mm, max {1e3 * res['max']:.3f} mm"
        f" over {res['n']} points (paper: {paper['mean']} ± {paper['std']} mm)",
    ]
    for key, val in rep["std"].items():
        if isinstance(val, dict):
            rot = ", ".join(f"{np.rad2deg(x):.4f}" for x in val["rotation_rad"])
            tr = ", ".join(f"{1e3 * x:.3f}" for x in val["translation_m"])
            lines.append(f"  std {key}: rotation [{rot}] deg, translation [{tr}] mm")
        else:
            unit = f"{np.rad2deg(val):.4f} deg" if ".r" in key else f"{1e3 * val:.3f} mm"
            lines.append(f"  std {key}: {unit}")
    for row in rep["unobservable"]:
        lines.append(f"  not calibrated: {row['direction']} -> {row['gauge']}")
    lines.extend(f"  warning: {w}" for w in rep["warnings"])
    return lines
