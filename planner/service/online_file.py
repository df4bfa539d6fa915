"""The online calibration's file and its history: FILE (the version in force, includable by
a scenario), ``FILE.versions/NNNN.yaml`` (every version; ``0000`` the calibration in force
before the first refit), the lock that makes numbering and writing one step, and
:func:`rollback` (``beamrelay calibrate rollback``). See :mod:`planner.service.online`.
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from ruamel.yaml import YAML, YAMLError

from planner.errors import InputError
from planner.model.system import System
from planner.model.transforms import Array, make_T, quat_to_matrix

ONLINE_MARK = "online"  # report key that marks a file written by the online refinement


def check_output_file(path: Path, scenario: Path) -> Path:
    """FILE for ``--online-calibration``: absolute; InputError if it is the scenario or an
    existing file the online refinement did not write (a user's calibration is never
    overwritten)."""
    path = Path(path).expanduser().resolve()
    if path == Path(scenario).resolve():
        raise InputError(f"--online-calibration {path}: that is the scenario itself")
    if path.is_dir():
        raise InputError(f"--online-calibration {path}: is a directory")
    if path.exists() and not is_online_file(path):
        raise InputError(
            f"--online-calibration {path}: exists and was not written by the online"
            " refinement; refusing to overwrite it (remove it or choose another file)"
        )
    return path


def is_online_file(path: Path) -> bool:
    """True when ``path`` is a calibration YAML whose report has the online mark."""

    try:
        doc = YAML(typ="safe", pure=True).load(Path(path).read_text())
    except (OSError, YAMLError, UnicodeDecodeError):
        return False
    rep = doc.get("report") if isinstance(doc, dict) else None
    return isinstance(rep, dict) and isinstance(rep.get(ONLINE_MARK), dict)


def write_atomically(path: Path, document: dict[str, Any]) -> None:
    """Write the calibration YAML to a temporary file next to ``path``, then rename it."""
    from planner.calibration.report import write_calibration

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    write_calibration(tmp, document)
    os.replace(tmp, path)


def history_dir(path: Path) -> Path:
    """The folder that keeps every version of the online calibration file ``path``."""
    return path.with_name(path.name + ".versions")


def history(path: Path) -> dict[int, Path]:
    """The kept versions of ``path``: ``{version: file}`` (``NNNN.yaml``, 4 digits or more)."""
    folder = history_dir(path)
    if not folder.is_dir():
        return {}
    return {int(f.stem): f for f in folder.glob("*.yaml") if re.fullmatch(r"\d{4,}", f.stem)}


@contextlib.contextmanager
def history_lock(path: Path) -> Iterator[None]:
    """Hold the history's lock (``FILE.versions/.lock``, an advisory ``flock``): numbering
    and writing a version, by the refit thread or by ``calibrate rollback``, is one step."""
    import fcntl

    folder = history_dir(path)
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".lock", "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def read_document(path: Path) -> dict[str, Any]:
    """A calibration YAML written by the online refinement (InputError naming the file)."""

    try:
        doc = YAML(typ="safe", pure=True).load(Path(path).read_text())
    except (OSError, YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read it: {exc}", str(path)) from None
    rep = doc.get("report") if isinstance(doc, dict) else None
    if not isinstance(rep, dict) or not isinstance(rep.get(ONLINE_MARK), dict):
        raise InputError("not a file written by the online calibration", str(path))
    online = rep[ONLINE_MARK]
    for key in ("version", "rolled_back_to", "previous_version"):
        value = online.get(key, 0)
        if key == "version" and "version" not in online:
            raise InputError("report.online.version is missing", str(path))
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise InputError(f"report.online.{key} is {value!r}, not a version number", str(path))
    return doc


def check_poses(doc: dict[str, Any], path: Path) -> None:
    """InputError unless ``doc`` holds a last mirror pose (and a laser pose, if any) as
    ``{xyz, quat}``: a version without poses cannot be installed."""
    try:
        sys_doc = doc["system"]
        poses = [sys_doc["robots"][-1]["mirror"]["flange_T_mirror"]]
        if "laser" in sys_doc:
            poses.append(sys_doc["laser"]["world_T_laser"])
        for pose in poses:
            if len(pose["xyz"]) != 3 or len(pose["quat"]) != 4:
                raise ValueError(pose)
            np.asarray([*pose["xyz"], *pose["quat"]], dtype=float)
    except (KeyError, IndexError, TypeError, ValueError):
        raise InputError("holds no mirror pose (system.robots[-1].mirror.flange_T_mirror"
                         " as xyz and quat): it cannot be installed", str(path)) from None  # fmt: skip


def version_of(doc: dict[str, Any]) -> int:
    """``report.online.version`` of an online calibration document."""
    return int(doc["report"][ONLINE_MARK]["version"])


def document_of(system: System, version: int, note: str) -> dict[str, Any]:
    """A calibration document holding ``system``'s laser and last mirror poses (the
    calibration in force before the first refit, kept as version 0 of the history)."""
    from planner.calibration.report import pose_dict

    robot = system.robots[-1]
    sys_doc: dict[str, Any] = {"robots": [{"name": robot.name, "mirror": {
        "flange_T_mirror": pose_dict(robot.mirror.flange_T_mirror)}}]}  # fmt: skip
    if system.n_robots == 1:
        sys_doc["laser"] = {"world_T_laser": pose_dict(system.world_T_laser)}
    return {"system": sys_doc, "report": {"kind": "online", "dataset": note,
                                          ONLINE_MARK: {"version": version}}}  # fmt: skip


def system_of(doc: dict[str, Any], nominal: System) -> System:
    """``nominal`` with the laser and last mirror poses of an online document."""

    def pose(d: dict[str, Any]) -> Array:
        return make_T(quat_to_matrix(np.asarray(d["quat"], dtype=float)), np.asarray(d["xyz"]))

    sys_doc = doc["system"]
    robot = sys_doc["robots"][-1]
    L = pose(sys_doc["laser"]["world_T_laser"]) if "laser" in sys_doc else nominal.world_T_laser
    return nominal.with_params(L, {robot["name"]: pose(robot["mirror"]["flange_T_mirror"])})


def refit_in_force(kept: dict[int, Path], doc: dict[str, Any], path: Path) -> dict[str, Any]:
    """The document of the refit whose poses ``doc`` holds: ``doc`` itself, or the version
    its ``rolled_back_to`` links lead to (InputError when a link is missing or loops)."""
    seen: set[int] = set()
    while (to := doc["report"][ONLINE_MARK].get("rolled_back_to")) is not None:
        if to in seen or to not in kept:
            raise InputError(f"the rollback chain of version {version_of(doc)} leads to version"
                             f" {to}, which is not kept", str(path))  # fmt: skip
        seen.add(to)
        doc = read_document(kept[to])
    return doc


def rollback(path: Path, to: int | None = None) -> tuple[int, int, int]:
    """Roll the online calibration ``path`` back to version ``to`` (default: the version in
    force before the refit whose poses are in force): a new version, numbered after every
    kept one, with version ``to``'s poses, written to the history and to ``path`` under the
    history's lock. Returns ``(new, to, was)``; InputError when ``path`` or its history does
    not allow it."""
    path = Path(path).expanduser().resolve()
    read_document(path)
    with history_lock(path):
        doc = read_document(path)
        was = version_of(doc)
        kept = history(path)
        if not kept:
            raise InputError(f"no kept versions in {history_dir(path)}", str(path))
        where = "--to"
        if to is None:
            where = str(path)
            refit_doc = refit_in_force(kept, doc, path)
            if version_of(refit_doc) == 0 or "previous_version" not in refit_doc["report"][
                    ONLINE_MARK]:  # fmt: skip
                raise InputError(f"version {was} has no earlier version to roll back to", where)
            to = int(refit_doc["report"][ONLINE_MARK]["previous_version"])
        if to not in kept:
            have = ", ".join(str(v) for v in sorted(kept))
            raise InputError(f"no version {to} is kept (kept: {have})", where)
        new = read_document(kept[to])
        check_poses(new, kept[to])
        new_version = max(max(kept), was) + 1
        new["report"]["dataset"] = f"rollback to version {to}"
        new["report"][ONLINE_MARK] = {"version": new_version, "rolled_back_to": to,
                                      "previous_version": was}  # fmt: skip
        write_atomically(history_dir(path) / f"{new_version:04d}.yaml", new)
        write_atomically(path, new)
    return new_version, to, was
