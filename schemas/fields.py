"""Reading one key of a JSON document into a typed field, without a pydantic pass: the key
or a :class:`~schemas.common.FieldError` naming its key path (``loc``), a string enum's
member or a FieldError listing the allowed values.

For documents the planner itself wrote (a plan, a reply), read at the size of their arrays;
files from elsewhere are validated by the pydantic models first.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Mapping
from enum import StrEnum
from typing import Any, TypeVar

from schemas.common import FieldError

Loc = tuple[str | int, ...]
E = TypeVar("E", bound=StrEnum)


def required(doc: Mapping[str, Any], key: str, loc: Loc) -> Any:
    """``doc[key]``; FieldError at ``loc`` when ``doc`` is no mapping, at ``loc.key`` when
    the key is missing."""
    if not isinstance(doc, Mapping):
        raise FieldError(loc, "expected a mapping")
    if key not in doc:
        raise FieldError((*loc, key), "required")
    return doc[key]


def opt_float(x: Any) -> float | None:
    """``x`` as a float, None as None."""
    return None if x is None else float(x)


def parse_enum(kind: type[E], value: Any, loc: Loc) -> E:
    """``value`` as a member of the string enum ``kind``; FieldError naming ``loc`` and the
    allowed values otherwise."""
    try:
        return kind(value)
    except ValueError:
        allowed = ", ".join(m.value for m in kind)
        raise FieldError(loc, f"unknown {_words(kind)} {value!r} ({allowed})") from None


def parse_either(kinds: tuple[type[StrEnum], ...], value: Any, loc: Loc) -> StrEnum:
    """``value`` as a member of the first of the string enums ``kinds`` that has it;
    FieldError naming ``loc`` and every allowed value otherwise."""
    for kind in kinds:
        with contextlib.suppress(ValueError):
            return kind(value)
    allowed = ", ".join(m.value for kind in kinds for m in kind)
    raise FieldError(loc, f"unknown {_words(kinds[0])} {value!r} ({allowed})")


def _words(kind: type[StrEnum]) -> str:
    """An enum's name as words: ``ServoStatus`` -> ``servo status``."""
    return re.sub(r"(?<!^)(?=[A-Z])", " ", kind.__name__).lower()
