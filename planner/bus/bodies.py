"""Untrusted JSON message bodies: parse any payload without crashing, name the bad field.

A body from the bus may be anything: binary garbage, NaN literals, integers of 10^5
digits (Python refuses to convert more than 4300), lone UTF-16 surrogate escapes
(``"\\ud800"``: valid JSON, but not text that can be encoded back), nesting 10^5 deep.
:func:`load_json` turns every such payload into plain data or one
:class:`~planner.errors.InputError` whose ``where`` is the offending key path (``body`` for
the document as a whole). :func:`safe_text` makes any string safe to put in a reply.
"""

from __future__ import annotations

import json
import re
from typing import Any

from planner.errors import InputError

#: integer literals longer than this (digits) do not fit a float; they stay a HugeNumber
MAX_INT_DIGITS = 300
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")


class HugeNumber:
    """An integer literal too long to be a number here; validation rejects it by its type.

    ``repr`` (used in error messages) says how many digits it had.
    """

    def __init__(self, text: str) -> None:
        self.digits = len(text.lstrip("-"))

    def __repr__(self) -> str:
        return f"a {self.digits}-digit integer"


def _parse_float(text: str) -> float:
    # a Python-level hook: lets other threads (the heartbeat) run while a body is parsed
    return float(text)


def _parse_int(text: str) -> int | HugeNumber:
    if len(text) > MAX_INT_DIGITS:
        return HugeNumber(text)
    return int(text)


def load_json(payload: bytes) -> Any:
    """Plain data of a UTF-8 JSON body; :class:`InputError` (``where`` = key path) if not.

    NaN/Infinity literals come back as floats (the schemas reject them by field); integers of
    more than :data:`MAX_INT_DIGITS` digits as :class:`HugeNumber`; strings holding a lone
    surrogate are refused here, at their key path.
    """
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"invalid JSON: body is not UTF-8 text (byte {exc.start} is 0x{payload[exc.start]:02x})",
            "body",
        ) from None
    try:
        data = json.loads(text, parse_int=_parse_int, parse_float=_parse_float)
    except RecursionError:
        raise InputError("JSON nested too deeply", "body") from None
    except ValueError as exc:  # JSONDecodeError and anything the number parsers raise
        raise InputError(f"invalid JSON: {safe_text(str(exc), 200)}", "body") from None
    if _SURROGATE_ESCAPE.search(text):
        bad = lone_surrogate_path(data)
        if bad is not None:
            raise InputError(
                "text holds a lone UTF-16 surrogate escape (not valid Unicode)", bad or "body"
            )
    return data


def _encodable(text: str) -> bool:
    if text.isascii():
        return True
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def lone_surrogate_path(data: Any) -> str | None:
    """Key path (``points[2]``, ``""`` for the top level) of the first string, key or value,
    holding a lone surrogate; None when all text is valid Unicode. Iterative: any depth."""
    stack: list[tuple[Any, str]] = [(data, "")]
    while stack:
        node, path = stack.pop()
        if isinstance(node, str):
            if not _encodable(node):
                return path
        elif isinstance(node, dict):
            for key, value in node.items():
                sub = f"{path}.{key}" if path else str(key)
                if not _encodable(key):
                    return safe_text(sub, 300)
                stack.append((value, sub))
        elif isinstance(node, list):
            stack.extend((value, f"{path}[{i}]") for i, value in enumerate(node))
    return None


def safe_text(text: str, limit: int = 2000) -> str:
    """``text`` as valid Unicode (lone surrogates written as ``\\udXXX``), at most ``limit``
    characters (the cut marked with ``...``)."""
    if not _encodable(text):
        text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    return text if len(text) <= limit else text[: max(limit - 3, 0)] + "..."


#: list items per call of the C JSON encoder in :func:`encode_json`
ENCODE_CHUNK = 256


def encode_json(obj: Any, chunk: int = ENCODE_CHUNK) -> bytes:
    """``json.dumps(obj, allow_nan=False)`` of plain data, encoded in pieces of at most
    ``chunk`` list items: the C encoder holds the GIL for a whole call (250 ms for a 4 MB
    plan), and the node's heartbeat thread must run every 10 ms. Same text as
    ``json.dumps`` (default separators)."""
    parts: list[str] = []
    _emit(obj, parts, chunk)
    return "".join(parts).encode()


def _emit(obj: Any, parts: list[str], chunk: int) -> None:
    if not _big(obj, chunk):
        parts.append(json.dumps(obj, allow_nan=False))
    elif isinstance(obj, dict):
        parts.append("{")
        for i, (key, value) in enumerate(obj.items()):
            parts.append((", " if i else "") + json.dumps(key) + ": ")
            _emit(value, parts, chunk)
        parts.append("}")
    else:
        parts.append("[")
        for start in range(0, len(obj), chunk):
            part = list(obj[start : start + chunk])
            parts.append(", " if start else "")
            if _big(part[0], chunk):
                for i, item in enumerate(part):
                    parts.append(", " if i else "")
                    _emit(item, parts, chunk)
            else:
                parts.append(json.dumps(part, allow_nan=False)[1:-1])
        parts.append("]")


def _big(obj: Any, chunk: int) -> bool:
    """Whether ``obj`` is worth splitting: a long list, or a container holding one (judged
    by the first item of lists)."""
    if isinstance(obj, dict):
        return all(isinstance(k, str) for k in obj) and any(_big(v, chunk) for v in obj.values())
    if isinstance(obj, list | tuple) and obj:
        return len(obj) > chunk or _big(obj[0], chunk)
    return False
