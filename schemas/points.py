"""The ``camera/points`` wire format: a raw float32 array with JSON metadata as attachment.

Payload: ``count`` rows of ``fields`` float32 values, row-major (``x, y, z`` in m in the
camera optical frame; an RGB camera adds ``r, g, b`` in [0, 1]). Attachment: the JSON of
:func:`points_metadata`. Pure (numpy only): the camera drivers write it, the operator console
and the tests read it.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from planner.errors import InputError

POINTS_SCHEMA = "beamrelay.points/1"
#: most points a sample may declare (a full 848 x 480 frame is 407 040)
MAX_POINTS = 4_000_000


def points_metadata(points: Any, t: float, seq: int, extra: dict[str, Any]) -> dict[str, Any]:
    """Attachment of a ``camera/points`` sample (all lengths in m, camera optical frame)."""
    fields = ["x", "y", "z", "r", "g", "b"][: points.shape[1]]
    return {
        "schema": POINTS_SCHEMA,
        "t": t,
        "seq": seq,
        "frame": "camera",
        "dtype": "float32",
        "fields": fields,
        "count": int(points.shape[0]),
        **extra,
    }


def decode_points(payload: bytes, attachment: bytes) -> tuple[Any, dict[str, Any]]:
    """``camera/points`` sample -> (count x len(fields) float32 array, metadata).

    InputError (``where``: ``attachment`` or ``payload``) for metadata that is not this
    schema, a count that does not fit the payload's length, or fields other than a prefix of
    ``x, y, z, r, g, b`` with at least ``x, y, z``."""
    try:
        meta = json.loads(attachment)
        fields, count = list(meta["fields"]), int(meta["count"])
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"bad points metadata: {exc}", "attachment") from exc
    if meta.get("schema") != POINTS_SCHEMA or meta.get("dtype") != "float32":
        raise InputError(
            f"expected {POINTS_SCHEMA} float32, got {meta.get('schema')}", "attachment"
        )
    if not 3 <= len(fields) <= 6 or fields != ["x", "y", "z", "r", "g", "b"][: len(fields)]:
        raise InputError(f"fields {fields}: expected x, y, z (+ r, g, b)", "attachment")
    if not 0 <= count <= MAX_POINTS:
        raise InputError(f"count {count} outside 0-{MAX_POINTS}", "attachment")
    if len(payload) != 4 * count * len(fields):
        raise InputError(f"{len(payload)} bytes for {count} x {len(fields)} float32", "payload")
    return np.frombuffer(payload, dtype=np.float32).reshape(count, len(fields)), meta
