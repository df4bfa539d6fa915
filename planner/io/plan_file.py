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

import io
import json
import mmap
import re
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import orjson

from planner.errors import InputError
from schemas.common import FieldError
from schemas.located import format_loc
from schemas.plan import Plan, check_tables, take_tables
from schemas.yamlio import read_json, validate

TABLES = ("t", "q", "qd", "qdd")  # the trajectory's dense tables
BIG = 1 << 16  # bytes of text from which a numeric array is parsed by numpy
WINDOW = 1 << 23  # bytes of text parsed at a time

_TOKEN = re.compile(rb'"(?:[^"\\]|\\.)*"|\[')  # a string (skipped whole) or an array's start
_NUMERIC = re.compile(rb"[0-9eE+\-.,\s\[\]]*")  # text that can only be numbers in arrays
_HOLE = b'"\\u0000plan-array-%d"'  # stands in the skeleton for the k-th carved array
_HOLE_TEXT = "\x00plan-array-"  # a hole as json reads it


def write_plan(doc: dict[str, Any], out: TextIO, digits: int = 10, chunk: int = 50_000) -> None:
    """Write plan.json text to ``out``: indented, but the dense ``trajectory`` rows written
    compactly with times, joints and their derivatives rounded to ``digits`` decimals
    (1e-10 rad by default; solutions keep full precision). Rows are formatted ``chunk`` at
    a time, so the extra memory does not grow with the trajectory. ValueError on a
    non-finite value in a table (JSON has none)."""
    traj = doc.get("trajectory")
    if not traj:
        out.write(_text(doc))
        return

    raw = getattr(out, "buffer", None)  # a file's bytes: the rows skip a decode and encode

    def rows(x: Any) -> None:
        out.write("[")
        if raw is not None:
            out.flush()
        for i in range(0, len(x), chunk):
            part = np.round(np.asarray(x[i : i + chunk], dtype=float), digits)
            if not np.all(np.isfinite(part)):
                raise ValueError("plan.json: a non-finite value in the trajectory")
            text = orjson.dumps(np.ascontiguousarray(part), option=orjson.OPT_SERIALIZE_NUMPY)
            text = (b"," if i else b"") + text[1:-1]
            if raw is not None:
                raw.write(text)
            else:
                out.write(text.decode())
        out.write("]")

    marker = "__TRAJECTORY__"
    head, tail = _text({**doc, "trajectory": marker}).split(json.dumps(marker), 1)
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


def _text(doc: dict[str, Any], one_per_line: int = 20) -> str:
    """JSON text of a document without its dense tables: a key per line, and a long list
    (solutions, targets) an item per line, each written by json's C encoder (an indented
    dump is pure Python: 8 s for 10^5 solutions)."""

    def value(v: Any) -> str:
        if isinstance(v, list) and len(v) > one_per_line:
            return "[\n  " + ",\n  ".join(json.dumps(item) for item in v) + "\n ]"
        return json.dumps(v)

    return "{\n" + ",\n".join(f" {json.dumps(k)}: {value(v)}" for k, v in doc.items()) + "\n}"


def plan_json(doc: dict[str, Any], digits: int = 10) -> str:
    """plan.json text (:func:`write_plan`) as a string."""

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
            skeleton, arrays = _carve(mm)
            try:
                return _with_tables(json.loads(skeleton), _Holes(arrays))
            except _ForgedHoleError:  # strings like our holes: read as json reads it, no carving
                return _with_tables(json.loads(mm[:]), None)


def load_plan(path: Path) -> dict[str, Any]:
    """plan.json read (its dense tables as arrays, :func:`~planner.io.plan_file.read_plan`)
    and validated against the schema: the tables with numpy, the rest by the model.
    InputError (one line, naming the file and the key path) when it is not a valid plan."""

    data = read_json(path, load=read_plan)
    if not isinstance(data, dict):
        raise InputError("expected a JSON object", str(path))
    tables = take_tables(data)
    validate(Plan, data, source=str(path))
    if tables is not None:
        try:
            check_tables(tables, data.get("joint_names") or {})
        except FieldError as exc:
            raise InputError(exc.reason, f"{path} {format_loc(('trajectory', *exc.loc))}") from None
        data["trajectory"].update(tables)
    return data


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
    """The index after the ``]`` that closes the ``[`` at ``start``, if before ``stop``
    (brackets counted a window at a time; the closing window scanned for the place)."""
    depth, o = 0, start
    while o < stop:
        w = min(WINDOW, stop - o)
        text = mm[o : o + w]
        _drop(mm, o, o + w)
        after = depth + text.count(b"[") - text.count(b"]")
        if after > 0:  # still open at the window's end
            depth, o = after, o + w
            continue
        a = np.frombuffer(text, np.uint8)
        d = depth + np.cumsum((a == 91).astype(np.int32) - (a == 93))
        return o + int(np.flatnonzero(d <= 0)[0]) + 1
    return None


def _drop(mm: mmap.mmap, a: int, b: int) -> None:
    """Give back the mapped pages of ``mm[a:b]`` read so far (they count as this process's
    memory while mapped; read again, they come back from the page cache)."""
    a -= a % mmap.PAGESIZE
    if b > a and hasattr(mm, "madvise"):
        mm.madvise(mmap.MADV_DONTNEED, a, min(b, len(mm)) - a)


def _parse(mm: mmap.mmap, start: int, end: int) -> np.ndarray | None:
    """The array ``mm[start:end]`` (a 1-D list of numbers, or a list of equally long rows
    of numbers), or None for any other shape or for text orjson rejects (json decides)."""
    head = re.match(rb"\[\s*(\[)?", mm[start : start + 64])
    rows = head is None or head.group(1) is not None
    sep = b"]" if rows else b","
    pieces: list[np.ndarray] = []
    o, b = start + 1, end - 1
    while o < b:
        cut = b if b - o <= WINDOW else mm.rfind(sep, o, o + WINDOW) + (1 if rows else 0)
        if cut <= o:  # a row or number longer than a window
            cut = mm.find(sep, o + 1, b) + (1 if rows else 0)
            cut = b if cut <= o else cut
        part = _window(mm[o:cut], rows, pieces[0].shape[1:] if pieces else None)
        _drop(mm, o, cut)
        if part is None:
            return None
        pieces.append(part)
        o = cut if rows else cut + 1  # past the separator (a row's comma is in the next window)
        if rows and o < b:
            nxt = mm.find(b"[", o, b)
            if nxt < 0 or mm[o:nxt].strip() != b",":
                return None
            o = nxt
    if not pieces:
        return None
    if any(p.dtype != pieces[0].dtype for p in pieces):
        pieces = [p.astype(float) for p in pieces]
    return pieces[0] if len(pieces) == 1 else np.concatenate(pieces)


def _window(text: bytes, rows: bool, shape: tuple[int, ...] | None) -> np.ndarray | None:
    """The numbers (or rows of ``shape``) of one window of an array's text, parsed by
    orjson, as strict as json; None for anything else, left to json to read or refuse."""
    try:
        a = np.array(orjson.loads(b"[" + text + b"]"))
    except (orjson.JSONDecodeError, ValueError):  # not JSON, ragged rows
        return None
    if a.dtype.kind not in "iuf" or a.ndim != (2 if rows else 1) or not a.size:
        return None
    if shape is not None and a.shape[1:] != shape:
        return None
    if a.dtype.kind == "f" and not any(c in text for c in (b".", b"e", b"E")):
        return None  # an integer beyond 64 bits, which json keeps exact
    return a


class _ForgedHoleError(Exception):
    """The document has a string of its own that reads like one of our holes."""


class _Holes:
    """The carved arrays, each taken once, from the hole that stands for it."""

    def __init__(self, arrays: list[np.ndarray]) -> None:
        self.arrays = arrays
        self.taken: set[int] = set()

    def take(self, value: Any) -> np.ndarray | None:
        """The array ``value`` stands for (None: not a hole). _ForgedHoleError for a string that reads
        like a hole but is not one of ours: an index out of range, or one taken already."""
        if not (isinstance(value, str) and value.startswith(_HOLE_TEXT)):
            return None
        k = value[len(_HOLE_TEXT) :]
        if not (k.isascii() and k.isdigit()) or int(k) >= len(self.arrays) or int(k) in self.taken:
            raise _ForgedHoleError
        self.taken.add(int(k))
        return self.arrays[int(k)]

    @property
    def left(self) -> bool:
        """Whether some carved array has not been taken yet."""
        return len(self.taken) < len(self.arrays)


def _with_tables(doc: Any, holes: _Holes | None) -> Any:
    """``doc`` with the trajectory's tables as float64 arrays and, given the carved arrays'
    ``holes``, every hole filled (every other carved array as the list json gives)."""
    traj = doc.get("trajectory") if isinstance(doc, dict) else None
    if isinstance(traj, dict):
        for key in set(TABLES) & set(traj):
            if key == "t":
                traj[key] = _table(traj[key], holes)
            elif isinstance(traj[key], dict):
                traj[key] = {r: _table(v, holes) for r, v in traj[key].items()}
    if holes is None or not holes.left:
        return doc
    return _filled(doc, holes)


def _table(value: Any, holes: _Holes | None) -> Any:
    """A trajectory table as a float array (left as it is when it is not numbers)."""
    carved = None if holes is None else holes.take(value)
    if carved is not None:
        return carved.astype(float, copy=False)
    try:  # a small table json read
        a = np.asarray(value)
    except ValueError:  # ragged: the checker reports it
        return value
    return a.astype(float) if a.dtype.kind in "iuf" else value  # not numbers: likewise


def _filled(x: Any, holes: _Holes) -> Any:
    if isinstance(x, dict):
        return {k: _filled(v, holes) for k, v in x.items()}
    if isinstance(x, list):
        return [_filled(v, holes) for v in x]
    carved = holes.take(x)
    return x if carved is None else carved.tolist()
