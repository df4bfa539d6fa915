"""Calibration datasets (docs/conventions.md): JSON files <-> the arrays the solvers use.

Validation happens here, at the boundary, with the pydantic models of
``schemas.calibration``; inside, datasets are :class:`HandEyeData` / :class:`BeamData`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from planner.calibration.beam import BeamData
from planner.calibration.handeye import HandEyeData
from planner.errors import DatasetError, InputError
from planner.model.system import System
from planner.model.transforms import Array, inv_T, transform_points
from schemas.calibration import BeamDataset, HandEyeDataset
from schemas.yamlio import read_json, validate


def load_handeye(path: str | Path) -> HandEyeData:
    """Read and validate a ``beamrelay.handeye/1`` file (DatasetError on any problem)."""

    raw = read_json(path, DatasetError)
    ds = validate(HandEyeDataset, raw, source=str(path), error_cls=DatasetError)
    nq = {len(s.q) for s in ds.samples}
    if len(nq) != 1:
        raise DatasetError(f"samples have different joint counts {sorted(nq)}", f"{path} samples")
    nan3 = [np.nan] * 3
    pts = np.array([[p if p is not None else nan3 for p in s.points_camera] for s in ds.samples])
    return HandEyeData(
        robot=ds.robot,
        mode=ds.mode,
        board_points=np.array(ds.board.points, dtype=float),
        q=np.array([s.q for s in ds.samples], dtype=float),
        points_camera=pts.astype(float),
    )


def load_beam(path: str | Path, system: System) -> BeamData:
    """Read and validate a ``beamrelay.beam/1`` file; ``spot_camera`` goes to the world with
    the scenario's camera pose (after its includes). A camera on a flange is posed at the
    sample's joints of its robot, which the sample's ``q`` must then hold."""

    raw = read_json(path, DatasetError)
    ds = validate(BeamDataset, raw, source=str(path), error_cls=DatasetError)
    names = system.robot_names
    if ds.robot not in names:
        raise DatasetError(
            f"unknown robot {ds.robot!r}; scenario robots: {', '.join(names)}", f"{path} robot"
        )
    chain = system.robots[: names.index(ds.robot) + 1]
    qs, spots, n_camera = [], [], 0
    for i, s in enumerate(ds.samples):
        row = []
        for r in chain:
            if r.name not in s.q:
                raise DatasetError(
                    f"no joints for {r.name!r} (needed up to {ds.robot!r})",
                    f"{path} samples[{i}].q",
                )
            if len(s.q[r.name]) != r.nq:
                raise DatasetError(
                    f"expected {r.nq} joints, got {len(s.q[r.name])}",
                    f"{path} samples[{i}].q.{r.name}",
                )
            row.extend(s.q[r.name])
        qs.append(row)
        if s.spot_world is not None:
            spots.append(np.array(s.spot_world, dtype=float))
        else:
            world_T_camera = _camera_pose(system, s.q, f"{path} samples[{i}]")
            spots.append(transform_points(world_T_camera, np.array(s.spot_camera)))
            n_camera += 1
    return BeamData(
        robot=ds.robot,
        q=np.array(qs, dtype=float),
        spots_world=np.array(spots),
        boards=np.array([s.board for s in ds.samples], dtype=int),
        camera_spots=n_camera,
    )


def _camera_pose(system: System, q: dict[str, list[float]], place: str) -> Array:
    """``world_T_camera`` at a sample's joints (a flange camera needs its robot's q)."""
    cam = system.camera
    if cam is None:
        raise DatasetError("spot_camera needs a camera in the scenario (system.camera)", place)
    if cam.robot is not None:
        r = system.robot(cam.robot)
        if cam.robot not in q:
            raise DatasetError(
                f"spot_camera with the camera on {cam.robot}'s flange needs {cam.robot}'s"
                " joints in q",
                f"{place}.q",
            )
        if len(q[cam.robot]) != r.nq:
            raise DatasetError(
                f"expected {r.nq} joints, got {len(q[cam.robot])}", f"{place}.q.{cam.robot}"
            )
    return system.world_T_camera({k: np.asarray(v, dtype=float) for k, v in q.items()})


def handeye_json(data: HandEyeData) -> dict[str, Any]:
    """The ``beamrelay.handeye/1`` mapping of a dataset (NaN points -> null)."""
    return {
        "schema": "beamrelay.handeye/1",
        "robot": data.robot,
        "mode": data.mode,
        "board": {"points": data.board_points.tolist()},
        "samples": [
            {
                "q": q.tolist(),
                "points_camera": [p.tolist() if np.all(np.isfinite(p)) else None for p in P],
            }
            for q, P in zip(data.q, data.points_camera, strict=True)
        ],
    }


def beam_json(data: BeamData, system: System, *, spots: str = "world") -> dict[str, Any]:
    """The ``beamrelay.beam/1`` mapping of a dataset.

    ``spots="world"`` writes ``spot_world``; ``"camera"`` writes ``spot_camera``, the spots
    in ``system.camera``'s optical frame at each sample's joints (a camera on a flange
    outside the chain is taken at its robot's home joints, written into ``q``).
    """
    if spots not in ("world", "camera"):
        raise ValueError(f"spots must be world or camera, got {spots!r}")
    names = system.robot_names
    chain = system.robots[: names.index(data.robot) + 1]
    cam = system.camera
    if spots == "camera" and cam is None:
        raise InputError("camera-frame spots need a camera in the scenario (system.camera)")
    samples = []
    for q, spot, b in zip(data.q, data.spots_world, data.boards, strict=True):
        split, i = {}, 0
        for r in chain:
            split[r.name] = q[i : i + r.nq].tolist()
            i += r.nq
        sample: dict[str, Any] = {"q": split, "board": int(b)}
        if spots == "world":
            sample["spot_world"] = spot.tolist()
        else:
            assert cam is not None
            if cam.robot is not None and cam.robot not in split:
                split[cam.robot] = system.robot(cam.robot).home.tolist()
            q_map = {k: np.asarray(v) for k, v in split.items()}
            camera_T_world = inv_T(system.world_T_camera(q_map))
            sample["spot_camera"] = transform_points(camera_T_world, spot).tolist()
        samples.append(sample)
    return {"schema": "beamrelay.beam/1", "robot": data.robot, "samples": samples}


def write_json(path: str | Path, document: dict[str, Any]) -> None:
    """Write a dataset mapping as JSON (full float precision)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=1) + "\n")
