"""Locating validation errors in a document: key paths, lines, plain-word reasons, merging.

An :data:`Origins` map remembers ``key path -> (file, line)`` for every key and list item
of a loaded document (see :mod:`schemas.yamlio`); :func:`validate` turns a pydantic
``ValidationError`` into one located :class:`~planner.errors.InputError` such as
``scenarios/x.yaml:14 system.robots[0].mirror.size: expected 2 numbers, got 3``.
:func:`merge_partial` applies ``include:`` / ``truth`` overrides and keeps origins right.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import re
import types
import typing
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

from planner.errors import InputError
from schemas.common import FieldError

Loc = tuple[str | int, ...]
Origins = dict[Loc, tuple[str, int]]
"""Key path -> (file as shown to the user, 1-based line of the key or list item; 0 = none)."""
M = TypeVar("M", bound=BaseModel)

POSE_KEY = re.compile(r"^\w+_T_\w+$")
"""Keys holding a pose; a pose is replaced whole when merged, never key by key."""
EXCLUSIVE_KEYS: dict[str, tuple[frozenset[str], ...]] = {
    "camera": (frozenset({"world_T_camera"}), frozenset({"robot", "flange_T_camera"})),
}
"""Mappings holding alternative key groups (a camera is fixed or on a flange): an override
giving keys of one group removes the other group's keys from the mapping it merges into."""


# --- error reporting ----------------------------------------------------------------------
def format_loc(loc: Loc) -> str:
    """``("system", "robots", 0, "mirror")`` -> ``system.robots[0].mirror``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def where(origins: Origins, loc: Loc, default_file: str = "") -> str:
    """``file:line key.path`` for a key path (line of the nearest existing parent)."""
    for n in range(len(loc), -1, -1):
        if loc[:n] in origins:
            shown, line = origins[loc[:n]]
            shown = f"{shown}:{line}" if line > 0 else shown
            return f"{shown} {format_loc(loc)}".strip()
    return f"{default_file} {format_loc(loc)}".strip()


def validation_error(
    exc: ValidationError,
    *,
    origins: Origins | None = None,
    source: str = "",
    prefix: Loc = (),
    error_cls: type[InputError] = InputError,
    model: type[BaseModel] | None = None,
) -> InputError:
    """The first error (by file line, missing keys last) of a ``ValidationError``, located."""
    found = []
    for order, err in enumerate(exc.errors()):
        loc, reason = explain(err, model)
        full = (*prefix, *loc)
        place = where(origins or {}, full, source)
        line = _line_of(origins or {}, full)
        # a missing key sits at its parent's line; a misspelt sibling explains it better
        found.append((err["type"] == "missing", line, order, reason, place))
    *_, reason, place = min(found)
    return error_cls(reason, place)


def _line_of(origins: Origins, loc: Loc) -> int:
    for n in range(len(loc), -1, -1):
        if loc[:n] in origins:
            return origins[loc[:n]][1]
    return 0


def validate(
    model: type[M],
    data: Any,
    *,
    origins: Origins | None = None,
    source: str = "",
    prefix: Loc = (),
    error_cls: type[InputError] = InputError,
) -> M:
    """``model.model_validate(data)``, raising a located ``error_cls`` instead."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        located = validation_error(
            exc, origins=origins, source=source, prefix=prefix, error_cls=error_cls, model=model
        )
        raise located from None


def explain(err: ErrorDetails, model: type[BaseModel] | None = None) -> tuple[Loc, str]:
    """(key path, plain reason) of one pydantic error."""
    loc: Loc = tuple(err["loc"])
    kind, ctx, value = err["type"], err.get("ctx") or {}, err.get("input")
    if kind in ("value_error", "assertion_error"):
        cause = ctx.get("error")
        if isinstance(cause, FieldError):
            return (*loc, *cause.loc), cause.reason
        return loc, str(cause) if cause is not None else err["msg"]
    if kind in ("extra_forbidden", "unexpected_keyword_argument"):  # a model's, a dataclass's
        return loc, _unknown_key(model, loc)
    if kind == "missing":
        return loc, "missing required key"
    if kind in ("too_short", "too_long"):
        bound = "at least" if kind == "too_short" else "at most"
        limit = ctx.get("min_length", ctx.get("max_length"))
        noun = "item" if limit == 1 else "items"
        return loc, f"expected {bound} {limit} {noun}, got {ctx.get('actual_length', '?')}"
    simple = {
        "number_type": "expected a number",
        "float_type": "expected a number",
        "float_parsing": "expected a number",
        "int_type": "expected an integer",
        "int_parsing": "expected an integer",
        "int_from_float": "expected an integer",
        "bool_type": "expected true or false",
        "bool_parsing": "expected true or false",
        "string_type": "expected a string",
        "list_type": "expected a list",
        "tuple_type": "expected a list",
        "dict_type": "expected a mapping",
        "model_type": "expected a mapping",
        "model_attributes_type": "expected a mapping",
    }
    if kind in simple:
        return loc, f"{simple[kind]}, got {describe(value)}"
    if kind in ("literal_error", "enum"):
        return loc, f"expected {ctx.get('expected')}, got {describe(value)}"
    bounds = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<"}
    bounds["less_than_equal"] = "<="
    if kind in bounds:
        limit = next(iter(ctx.values()), "?")
        return loc, f"must be {bounds[kind]} {limit}, got {describe(value)}"
    if kind == "string_too_short":
        return loc, "must not be empty"
    return loc, str(err["msg"])


def describe(value: Any) -> str:
    """Short description of an offending value for messages."""
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list | tuple):
        return f"a list of {len(value)}"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _unknown_key(model: type[BaseModel] | None, loc: Loc) -> str:
    allowed = _keys_at(model, loc[:-1]) if model is not None else None
    if not allowed:
        return "unknown key"
    close = difflib.get_close_matches(str(loc[-1]), allowed, n=1)
    if close:
        return f"unknown key (did you mean {close[0]!r}?)"
    return f"unknown key (allowed: {', '.join(allowed)})"


def _keys_at(model: type[BaseModel], loc: Loc) -> list[str] | None:
    """Keys the model accepts at a key path, following fields, lists and dicts."""
    tp: Any = model
    for part in loc:
        tp = _unwrap(tp)
        fields = _fields_of(tp)
        if fields is not None:
            if part not in fields:
                return None
            tp = fields[str(part)]
        elif typing.get_origin(tp) in (list, dict):
            tp = typing.get_args(tp)[-1]
        else:
            return None
    fields = _fields_of(_unwrap(tp))
    return None if fields is None else list(fields)


def _fields_of(tp: Any) -> dict[str, Any] | None:
    """Key -> type of a model's or a dataclass's fields (None for any other type)."""
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return {f.alias or n: f.annotation for n, f in tp.model_fields.items()}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        hints = typing.get_type_hints(tp, include_extras=True)
        return {f.name: hints[f.name] for f in dataclasses.fields(tp)}
    return None


def _unwrap(tp: Any) -> Any:
    while True:
        origin = typing.get_origin(tp)
        if origin is typing.Annotated:
            tp = typing.get_args(tp)[0]
        elif origin in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) != 1:
                return tp
            tp = args[0]
        else:
            return tp


# --- merging (include files, truth) -------------------------------------------------------
def merge_partial(
    base: dict[str, Any],
    over: dict[str, Any],
    *,
    origins: Origins,
    over_origins: Origins,
    base_loc: Loc = (),
    over_loc: Loc = (),
    error_cls: type[InputError] = InputError,
) -> None:
    """Merge ``over`` into ``base`` in place (docs/conventions.md: Scenario YAML, ``include:``).

    Mappings merge key by key; poses (``*_T_*`` keys), lists and scalars replace whole;
    ``robots`` lists are matched by ``name`` (an unknown name is an error located in
    ``over``). ``origins`` is updated so replaced values point into ``over``'s file.
    """
    for key, value in over.items():
        b_loc, o_loc = (*base_loc, key), (*over_loc, key)
        current = base.get(key)
        if key == "robots" and isinstance(current, list) and isinstance(value, list):
            for j, robot in enumerate(value):
                name = robot.get("name") if isinstance(robot, dict) else None
                i = next(
                    (
                        i
                        for i, r in enumerate(current)
                        if isinstance(r, dict) and r.get("name") == name
                    ),
                    None,
                )
                if i is None or not isinstance(robot, dict):
                    known = ", ".join(str(r.get("name")) for r in current if isinstance(r, dict))
                    place = where(over_origins, (*o_loc, j, "name"))
                    raise error_cls(f"no robot named {name!r} (robots: {known})", place)
                merge_partial(
                    current[i],
                    robot,
                    origins=origins,
                    over_origins=over_origins,
                    base_loc=(*b_loc, i),
                    over_loc=(*o_loc, j),
                    error_cls=error_cls,
                )
        elif isinstance(current, dict) and isinstance(value, dict) and not POSE_KEY.match(str(key)):
            _drop_alternatives(current, value, EXCLUSIVE_KEYS.get(str(key), ()), origins, b_loc)
            merge_partial(
                current,
                value,
                origins=origins,
                over_origins=over_origins,
                base_loc=b_loc,
                over_loc=o_loc,
                error_cls=error_cls,
            )
        else:
            base[key] = copy.deepcopy(value)
            _replace_origins(origins, over_origins, b_loc, o_loc)


def _drop_alternatives(
    base: dict[str, Any],
    over: dict[str, Any],
    groups: tuple[frozenset[str], ...],
    origins: Origins,
    b_loc: Loc,
) -> None:
    for group in groups:
        if group & over.keys():
            for other in groups:
                for key in other - group:
                    if base.pop(key, None) is not None:
                        _replace_origins(origins, {}, (*b_loc, key), ())


def _replace_origins(origins: Origins, over_origins: Origins, b_loc: Loc, o_loc: Loc) -> None:
    n, m = len(b_loc), len(o_loc)
    for loc in [loc for loc in origins if loc[:n] == b_loc]:
        del origins[loc]
    for loc, origin in over_origins.items():
        if loc[:m] == o_loc:
            origins[(*b_loc, *loc[m:])] = origin


def rebase_origins(origins: Origins, old: Loc, new: Loc) -> Origins:
    """The entries under ``old`` re-keyed under ``new`` (others dropped)."""
    n = len(old)
    return {(*new, *loc[n:]): o for loc, o in origins.items() if loc[:n] == old}
