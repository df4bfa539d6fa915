"""plan.json text, written and read without the dense trajectory as Python lists.

:func:`write_plan` writes the trajectory's tables (``t``, ``q``, ``qd``, ``qdd``; numpy arrays
or lists) a chunk of rows at a time with orjson. :func:`read_plan` reads what ``json.load``
would, except that the trajectory's tables come back as float64 numpy arrays: every large
numeric array (:data:`BIG` bytes of text or more) is parsed by numpy straight from a memory
map, so a plan of millions of samples reads in about the memory of its arrays. Anything the
fast path does not recognise (a ragged table, NaN, a malformed number) is left to ``json``,
which decides what it means or rejects it.
"""

from __future__ import annotations

import json
import mmap
import re
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import orjson

TABLES = ("t", "q", "qd", "qdd")  # the trajectory's dense tables
BIG = 1 << 16  # bytes of text from which a numeric array is parsed by numpy
WINDOW = 1 << 23  # bytes of text parsed at a time

_TOKEN = re.compile(rb'"(?:[^"\\]|\\.)*"|\[')  # a string (skipped whole) or an array's start
_NUMERIC = re.compile(rb"[0-9eE+\-.,\s\[\]]*")  # text that can only be numbers in arrays
_HOLE = b'"\\u0000plan-array-%d"'  # stands in the skeleton for the k-th carved array
_HOLE_TEXT = "\x00plan-array-"
_UNBRACKET = bytes.maketrans(b"[]", b"  ")


def write_plan(doc: dict[str, Any], out: TextIO, digits: int = 10, chunk: int = 50_000) -> None:
    """Write plan.json text to ``out``: indented, but the dense ``trajectory`` rows written
    compactly with times, joints and their derivatives rounded to ``digits`` decimals
    (1e-10 rad by default; solutions keep full precision). Rows are formatted ``chunk`` at
    a time, so the extra memory does not grow with the trajectory. ValueError on a
    non-finite value in a table (JSON has none)."""
    traj = doc.get("trajectory")
    if not traj:
        out.write(json.dumps(doc, indent=1))
        return

    def rows(x: Any) -> None:
        out.write("[")
        for i in range(0, len(x), chunk):
            part = np.round(np.asarray(x[i : i + chunk], dtype=float), digits)
            if not np.all(np.isfinite(part)):
                raise ValueError("plan.json: a non-finite value in the trajectory")
            text = orjson.dumps(np.ascontiguousarray(part), option=orjson.OPT_SERIALIZE_NUMPY)
            out.write(("," if i else "") + text[1:-1].decode())
        out.write("]")

    marker = "__TRAJECTORY__"
    head, tail = json.dumps({**doc, "trajectory": marker}, indent=1).split(json.dumps(marker), 1)
    out.write(head + '{"t":')
    rows(traj["t"])
    for key in ("q", "qd", "qdd"):
        out.write(f',\n"{key}":{{')
        for n, (robot, table) in enumerate(traj[key].items()):
            out.write(("," if n else "") + json.dumps(robot) + ":")
            rows(table)
        out.write("}")
    out.write(f',\n"segments":{json.dumps(traj.get("segments", []))}')
    for key, value in traj.items():  # small extra keys (laser_on, slowdowns, ...)
        if key not in ("t", "q", "qd", "qdd", "segments"):
            out.write(f",\n{json.dumps(key)}:{json.dumps(value)}")
    out.write("}" + tail)


def plan_json(doc: dict[str, Any], digits: int = 10) -> str:
    """plan.json text (:func:`write_plan`) as a string."""
    import io

    buf = io.StringIO()
    write_plan(doc, buf, digits)
    return buf.getvalue()


def read_plan(path: Path) -> Any:
    """The JSON document in ``path``, as ``json.load`` reads it, except that the
    ``trajectory``'s ``t``, ``q``, ``qd`` and ``qdd`` tables are float64 arrays (and a large
    numeric array elsewhere is parsed by numpy, then given back as a list).
    ``json.JSONDecodeError`` (a ValueError) on text that is not JSON."""
    with path.open("rb") as fh:
        if fh.seek(0, 2) == 0:
            return json.loads(b"")  # raises, as json.load does
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            if mm.find(_HOLE_TEXT.encode()) >= 0 or mm.find(b"\\u0000plan-array-") >= 0:
                return _with_tables(json.loads(mm[:]), None)  # a document naming our holes
            skeleton, arrays = _carve(mm)
    return _with_tables(json.loads(skeleton), arrays)


def _carve(mm: mmap.mmap) -> tuple[bytes, list[np.ndarray]]:
    """The text with every large numeric array replaced by a hole (a string), and the
    arrays. Strings are skipped whole, so a ``[`` is only ever taken outside them."""
    parts: list[bytes] = []
    arrays: list[np.ndarray] = []
    prev = pos = 0
    while (m := _TOKEN.search(mm, pos)) is not None:
        start = m.start()
        if mm[start] == ord('"'):
            pos = m.end()
            continue
        run = _NUMERIC.match(mm, start)
        run_end = start + 1 if run is None else run.end()
        if run_end - start < BIG:
            pos = start + 1
            continue
        end = _closing(mm, start, run_end)
        arr = None if end is None else _parse(mm, start, end)
        if end is None or arr is None:  # left to json
            pos = run_end if end is None else end
            continue
        parts += [mm[prev:start], _HOLE % len(arrays)]
        arrays.append(arr)
        prev = pos = end
    parts.append(mm[prev:])
    return b"".join(parts), arrays


def _closing(mm: mmap.mmap, start: int, stop: int) -> int | None:
    """The index after the ``]`` that closes the ``[`` at ``start``, if before ``stop``."""
    depth, o = 0, start
    while o < stop:
        w = min(WINDOW, stop - o)
        a = np.frombuffer(mm, np.uint8, w, o)
        d = depth + np.cumsum((a == 91).astype(np.int32) - (a == 93))
        del a
        shut = np.flatnonzero(d <= 0)
        if len(shut):
            return o + int(shut[0]) + 1
        depth, o = int(d[-1]), o + w
    return None


def _parse(mm: mmap.mmap, start: int, end: int) -> np.ndarray | None:
    """The array ``mm[start:end]`` (a 1-D list of numbers, or a list of equally long rows
    of numbers), or None for any other shape or text numpy cannot read exactly."""
    head = re.match(rb"\[\s*(\[)?", mm[start : start + 64])
    try:
        if head is not None and head.group(1) is None:
            return _numbers(mm, start + 1, end - 1)
        return _rows(mm, start + 1, end - 1)
    except ValueError:  # np.fromstring: a malformed number
        return None


def _read(text: bytes) -> np.ndarray:
    """The numbers in ``text`` (separated by commas and blanks): integers when none has a
    point or exponent (as json gives them), else floats. ValueError if one is malformed or
    beyond int64 (numpy would saturate it; json keeps it exact)."""
    if any(c in text for c in (b".", b"e", b"E")):
        return np.fromstring(text, dtype=float, sep=",")
    vals = np.fromstring(text, dtype=np.int64, sep=",")
    if np.any((vals >= 2**62) | (vals <= -(2**62))):
        raise ValueError("an integer beyond int64")
    return vals


def _numbers(mm: mmap.mmap, a: int, b: int) -> np.ndarray | None:
    """Comma-separated numbers in ``mm[a:b]``, read a window at a time (cut at a comma)."""
    pieces, o = [], a
    while o < b:
        cut = b if b - o <= WINDOW else mm.rfind(b",", o, o + WINDOW)
        if cut <= o:  # a number longer than a window
            cut = mm.find(b",", o + 1, b) if mm.find(b",", o + 1, b) > o else b
        text = mm[o:cut]
        vals = _read(text)
        if len(vals) != text.count(b",") + 1:  # "1,,2" or a trailing comma
            return None
        pieces.append(vals)
        o = cut + 1
    return _joined(pieces)


def _rows(mm: mmap.mmap, a: int, b: int) -> np.ndarray | None:
    """Rows ``[x,...],[y,...]`` of one length in ``mm[a:b]``, a window of whole rows at a time."""
    pieces, o, width = [], a, None
    while o < b:
        cut = b if b - o <= WINDOW else mm.rfind(b"]", o, o + WINDOW) + 1
        if cut <= o:  # a row longer than a window
            cut = mm.find(b"]", o, b) + 1
        if cut <= o:
            return None
        text = mm[o:cut]
        got = _window_rows(text, width)
        if got is None:
            return None
        vals, width = got
        pieces.append(vals)
        if cut == b:
            break
        nxt = mm.find(b"[", cut, b)  # the next row, after one comma
        if nxt < 0 or mm[cut:nxt].strip() != b",":
            return None
        o = nxt
    return _joined(pieces)


def _window_rows(text: bytes, width: int | None) -> tuple[np.ndarray, int] | None:
    """The rows in ``text`` (whole rows, separated by one comma) as a 2-D array, and their
    length; None unless every row has ``width`` numbers (the first row's, if None)."""
    a = np.frombuffer(text, np.uint8)
    opens, closes = np.flatnonzero(a == 91), np.flatnonzero(a == 93)
    if not len(opens) or len(opens) != len(closes):
        return None
    if np.any(opens >= closes) or np.any(closes[:-1] >= opens[1:]):
        return None  # nested deeper than rows
    commas = np.cumsum(a == 44)
    inside = commas[closes] - commas[opens]
    width = int(inside[0]) + 1 if width is None else width
    between = commas[opens[1:]] - commas[closes[:-1]]
    if np.any(inside != width - 1) or np.any(between != 1):
        return None
    flat = text.translate(_UNBRACKET)
    if not flat.strip(b" \t\r\n,"):
        return None  # empty rows: json's
    vals = _read(flat)
    if len(vals) != len(opens) * width:
        return None
    return vals.reshape(len(opens), width), width


def _joined(pieces: list[np.ndarray]) -> np.ndarray:
    if len(pieces) == 1:
        return pieces[0]
    if any(p.dtype != pieces[0].dtype for p in pieces):
        pieces = [p.astype(float) for p in pieces]
    return np.concatenate(pieces)


def _with_tables(doc: Any, arrays: list[np.ndarray] | None) -> Any:
    """``doc`` with the trajectory's tables as float64 arrays and, given the carved
    ``arrays``, its holes filled (every other carved array as the list json gives)."""
    traj = doc.get("trajectory") if isinstance(doc, dict) else None
    if isinstance(traj, dict):
        for key in set(TABLES) & set(traj):
            if key == "t":
                traj[key] = _table(traj[key], arrays)
            elif isinstance(traj[key], dict):
                traj[key] = {r: _table(v, arrays) for r, v in traj[key].items()}
    return doc if arrays is None else _filled(doc, arrays)


def _table(value: Any, arrays: list[np.ndarray] | None) -> Any:
    """A trajectory table as a float array (left as it is when it is not numbers)."""
    k = _hole(value)
    if k is not None and arrays is not None:
        return arrays[k].astype(float, copy=False)
    try:  # a small table json read
        a = np.asarray(value)
    except ValueError:  # ragged: the checker reports it
        return value
    return a.astype(float) if a.dtype.kind in "iuf" else value  # not numbers: likewise


def _hole(value: Any) -> int | None:
    if isinstance(value, str) and value.startswith(_HOLE_TEXT):
        return int(value[len(_HOLE_TEXT) :])
    return None


def _filled(x: Any, arrays: list[np.ndarray]) -> Any:
    if isinstance(x, dict):
        return {k: _filled(v, arrays) for k, v in x.items()}
    if isinstance(x, list):
        return [_filled(v, arrays) for v in x]
    k = _hole(x)
    return x if k is None else arrays[k].tolist()
