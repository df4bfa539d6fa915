"""Reading beamrelay files and messages into schema models, with located errors.

YAML is read as YAML 1.2 with ruamel's round-trip loader so every key and list item keeps
its line; the tree becomes plain Python (dict, list, float, int, bool, str, None) plus an
:data:`~schemas.located.Origins` map. JSON is read with the standard library (errors name
the key path, no line). :func:`read_tagged` tells what a file is and validates it (a scenario is only detected: the
planner resolves it).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel
from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap, CommentedSeq
from ruamel.yaml.error import MarkedYAMLError, YAMLError

from planner.errors import DatasetError, InputError, ScenarioError
from schemas.calibration import (
    BEAM_SCHEMA,
    HANDEYE_SCHEMA,
    BeamDataset,
    CalibrationFile,
    HandEyeDataset,
)
from schemas.located import (
    Loc,
    Origins,
    format_loc,
    merge_partial,
    rebase_origins,
    validate,
    validation_error,
    where,
)
from schemas.messages import (
    ERROR_SCHEMA,
    JOINT_STATE_SCHEMA,
    REQUEST_SCHEMA,
    SPOT_SCHEMA,
    STATUS_SCHEMA,
    TRAJECTORY_SCHEMA,
    ErrorReply,
    JointState,
    JointTrajectory,
    RobotStatus,
    SpotMessage,
    TargetRequest,
)
from schemas.plan import PLAN_SCHEMA, Plan
from schemas.scenario import Scenario

__all__ = [
    "Loc",
    "Origins",
    "format_loc",
    "load_dataset",
    "load_model",
    "merge_partial",
    "parse_message",
    "read_document",
    "read_json",
    "read_tagged",
    "read_yaml",
    "rebase_origins",
    "validate",
    "validation_error",
    "where",
]
M = TypeVar("M", bound=BaseModel)


# --- loading ------------------------------------------------------------------------------
def read_yaml(
    path: str | Path, error_cls: type[InputError] = InputError, *, shown: str | None = None
) -> tuple[Any, Origins]:
    """Load a YAML 1.2 file as plain Python plus the line of every key and item.

    ``shown`` is the file name used in messages (default: ``path`` as given).
    """
    shown = str(path) if shown is None else shown
    text = _read_text(path, error_cls, shown)
    yaml = YAML(typ="rt")
    yaml.version = (1, 2)
    try:
        node = yaml.load(text)
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f":{mark.line + 1}" if mark is not None else ""
        reason = " ".join(str(s) for s in (exc.context, exc.problem) if s) or "invalid YAML"
        raise error_cls(f"YAML syntax error: {reason}", f"{shown}{line}") from None
    except YAMLError as exc:
        raise error_cls(f"YAML syntax error: {exc}", shown) from None
    origins: Origins = {(): (shown, 1)}
    return _plain(node, (), shown, origins), origins


def read_json(
    path: str | Path,
    error_cls: type[InputError] = InputError,
    load: Callable[[Path], Any] | None = None,
) -> Any:
    """Load a JSON file (no line tracking: errors name the key path). ``load`` reads the
    file another way (a path -> document function raising what ``json`` and ``open`` raise,
    e.g. :func:`planner.io.plan_file.read_plan`), with the same one-line errors."""
    try:
        return (load or _load_json)(Path(path))
    except FileNotFoundError:
        raise error_cls("file not found", str(path)) from None
    except json.JSONDecodeError as exc:
        raise error_cls(f"JSON syntax error: {exc.msg}", f"{path}:{exc.lineno}") from None
    except (OSError, UnicodeDecodeError) as exc:  # a directory, unreadable, not UTF-8
        raise error_cls(f"cannot read file: {exc}", str(path)) from None


def _load_json(path: Path) -> Any:
    return json.loads(path.read_text(encoding="utf-8"))


def _read_text(path: str | Path, error_cls: type[InputError], shown: str) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error_cls("file not found", shown) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error_cls(f"cannot read file: {exc}", shown) from None


def _plain(node: Any, loc: Loc, shown: str, origins: Origins) -> Any:
    here = origins.get(loc, (shown, 1))
    if isinstance(node, CommentedMap):
        out = {}
        for key, value in node.items():
            k = _plain_scalar(key)
            positions = node.lc.data  # keys merged in from an anchor (<<: *x) have none
            origins[(*loc, k)] = (shown, positions[key][0] + 1) if key in positions else here
            out[k] = _plain(value, (*loc, k), shown, origins)
        return out
    if isinstance(node, CommentedSeq):
        items = []
        for i, value in enumerate(node):
            positions = node.lc.data
            origins[(*loc, i)] = (shown, positions[i][0] + 1) if i in positions else here
            items.append(_plain(value, (*loc, i), shown, origins))
        return items
    return _plain_scalar(node)


def _plain_scalar(value: Any) -> Any:
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, int) and type(value).__name__ == "ScalarBoolean":
        return bool(value)
    for kind in (int, float, str):
        if isinstance(value, kind):
            return kind(value)
    return value


# --- documents -----------------------------------------------------------------------------

SCHEMAS: dict[str, tuple[str, type[BaseModel]]] = {
    PLAN_SCHEMA: ("plan", Plan),
    HANDEYE_SCHEMA: ("handeye", HandEyeDataset),
    BEAM_SCHEMA: ("beam", BeamDataset),
    REQUEST_SCHEMA: ("request", TargetRequest),
    TRAJECTORY_SCHEMA: ("trajectory", JointTrajectory),
    JOINT_STATE_SCHEMA: ("joint_state", JointState),
    STATUS_SCHEMA: ("status", RobotStatus),
    SPOT_SCHEMA: ("spot", SpotMessage),
    ERROR_SCHEMA: ("error", ErrorReply),
}
"""``schema`` field value -> (kind, model)."""
DATASET_KINDS = ("handeye", "beam")


def _error_cls(kind: str) -> type[InputError]:
    if kind in DATASET_KINDS:
        return DatasetError
    return ScenarioError if kind in ("scenario", "calibration") else InputError


def read_document(
    path: str | Path, error_cls: type[InputError] = InputError
) -> tuple[Any, Origins | None]:
    """A JSON (``*.json``, no line numbers) or YAML file as plain data plus its origins."""
    if Path(path).suffix.lower() == ".json":
        return read_json(path, error_cls), None
    return read_yaml(path, error_cls)


def load_model(path: str | Path, model: type[M], error_cls: type[InputError] = InputError) -> M:
    """Read a JSON/YAML file and validate it as ``model`` (errors name file, line, key)."""
    data, origins = read_document(path, error_cls)
    return validate(model, data, origins=origins, source=str(path), error_cls=error_cls)


def load_dataset(path: str | Path) -> HandEyeDataset | BeamDataset:
    """A calibration dataset (hand-eye or beam) chosen by its ``schema`` field."""
    kind, model = read_tagged(path)
    if not isinstance(model, HandEyeDataset | BeamDataset):
        raise DatasetError(f"is a {kind} file, not a calibration dataset", str(path))
    return model


def parse_message(body: bytes | str, model: type[M]) -> M:
    """A JSON message body as ``model``; on error ``InputError.where`` is the key path."""
    try:
        data = json.loads(body)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"invalid JSON: {exc}") from None
    return validate(model, data)


SCENARIO_KIND = "scenario"
"""The kind :func:`read_tagged` gives a scenario file (resolved by the planner, not here)."""


def read_tagged(path: str | Path) -> tuple[str, BaseModel | None]:
    """Detect what a file is and validate it, except a scenario; returns ``(kind, model)``.

    Kinds: ``calibration``, the ``schema``-tagged ``plan`` (its ``scenario`` validated as
    well), ``handeye``, ``beam``, ``request``, ``trajectory``, ``joint_state``, ``status``,
    ``spot``, ``error``; and ``scenario`` with model None (its includes, robots, limits and
    targets are resolved by :func:`planner.io.validate.validate_file`). Raises
    :class:`InputError` (or its Scenario/Dataset subclasses).
    """
    shown = str(path)
    data, origins = read_document(path)
    if not isinstance(data, dict):
        reason = "file is empty" if data is None else "expected a mapping of keys at the top level"
        raise InputError(reason, where(origins or {}, (), shown))
    schema = data.get("schema")
    if schema is not None:
        if schema not in SCHEMAS:
            known = ", ".join(SCHEMAS)
            place = where(origins or {}, ("schema",), shown)
            raise InputError(f"unknown schema {schema!r} (known: {known})", place)
        kind, model_cls = SCHEMAS[schema]
        kw: dict[str, Any] = {"origins": origins, "source": shown, "error_cls": _error_cls(kind)}
        model = validate(model_cls, data, **kw)
        if isinstance(model, Plan):
            validate(Scenario, model.scenario, **kw, prefix=("scenario",))
        return kind, model
    if "report" in data and "targets" not in data:
        return "calibration", validate(
            CalibrationFile, data, origins=origins, source=shown, error_cls=ScenarioError
        )
    if "system" in data or "targets" in data:
        return SCENARIO_KIND, None
    place = where(origins or {}, (), shown)
    raise InputError("cannot tell what this file is: no schema key and no scenario keys", place)
