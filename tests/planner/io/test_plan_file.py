"""plan.json written with orjson and read back through numpy: what json reads, tables as arrays.

Every document is compared with ``json.loads`` of the same text (the independent reader);
``BIG`` and ``WINDOW`` are made small so that the numpy path and its window cuts are taken
on documents of a few kilobytes."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.io import plan_file
from planner.io.plan_file import read_plan, write_plan


@pytest.fixture
def small_windows(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(plan_file, "BIG", 32)
    monkeypatch.setattr(plan_file, "WINDOW", 97)  # cuts inside rows and numbers


def as_json(x: Any) -> Any:
    """``x`` with arrays as lists, for comparing with json's reading."""
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, dict):
        return {k: as_json(v) for k, v in x.items()}
    if isinstance(x, list):
        return [as_json(v) for v in x]
    return x


def floats_or_as_is(v: Any) -> Any:
    try:
        return np.asarray(v, dtype=float).tolist()
    except ValueError:  # ragged: the reader leaves it to the checker
        return v


def same(back: Any, text: str) -> bool:
    """``back`` is what json reads in ``text``, with the trajectory's tables as floats
    (compared as JSON text: NaN equals NaN there, and 1 differs from 1.0)."""
    ref = json.loads(text)
    traj = ref.get("trajectory") if isinstance(ref, dict) else None
    for key in set(plan_file.TABLES) & set(traj or {}):
        tables = traj[key] if key != "t" else {"": traj[key]}
        floats = {r: floats_or_as_is(v) for r, v in tables.items()}
        traj[key] = floats[""] if key == "t" else floats
    return json.dumps(as_json(back), sort_keys=True) == json.dumps(ref, sort_keys=True)


def plan_doc(m: int, robots: tuple[str, ...] = ("arm0",), seed: int = 0) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    return {
        "schema": "beamrelay.plan/1",
        "solutions": [
            {
                "q": {r: rng.normal(size=6).tolist() for r in robots},
                "ok": True,
                "reason": 'a "quoted" [1,2,3] text',
            }
        ],
        "order": list(range(300)),  # a large array of integers outside the trajectory
        "trajectory": {
            "t": np.arange(m) * 0.002,
            "q": {r: rng.normal(size=(m, 6)) for r in robots},
            "qd": {r: rng.normal(size=(m, 6)) * 1e-7 for r in robots},
            "qdd": {r: rng.normal(size=(m, 6)) * 1e5 for r in robots},
            "segments": [{"kind": "move", "t0": 0.0, "t1": 0.002 * (m - 1)}],
            "laser_on": [[0.0, 0.5]],
        },
    }


def carved(path: Path) -> int:
    """How many arrays of the file numpy read."""
    import mmap

    with path.open("rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        return len(plan_file._carve(mm)[1])


def written(doc: dict[str, Any], tmp_path: Path, chunk: int = 50_000) -> Path:
    """The plan written to a file (its rows go to the file's bytes) and, the same text,
    to a string (its rows decoded)."""
    buf = io.StringIO()
    write_plan(doc, buf, chunk=chunk)
    path = tmp_path / "plan.json"
    with path.open("w") as fh:
        write_plan(doc, fh, chunk=chunk)
    assert path.read_text() == buf.getvalue()
    return path


@pytest.mark.parametrize("robots", [("arm0",), ("arm0", "arm1")])
def test_a_plan_reads_back_as_json_reads_it_with_array_tables(
    small_windows: None, tmp_path: Path, robots: tuple[str, ...]
) -> None:
    doc = plan_doc(400, robots)
    path = written(doc, tmp_path, chunk=33)
    back = read_plan(path)
    assert same(back, path.read_text())  # every number exactly as json parsed it
    # the tables, "order" and the solutions' joints (over BIG = 32 bytes) went through numpy
    assert carved(path) == 1 + 3 * len(robots) + 1 + len(robots)
    traj = back["trajectory"]
    assert isinstance(traj["t"], np.ndarray) and traj["t"].shape == (400,)
    for key in ("q", "qd", "qdd"):
        for r in robots:
            assert traj[key][r].dtype == float and traj[key][r].shape == (400, 6)
            # the writer rounds to 1e-10 (numpy's rounding is the independent reference)
            assert np.array_equal(traj[key][r], np.round(doc["trajectory"][key][r], 10))
    assert back["order"] == list(range(300)) and all(type(k) is int for k in back["order"])
    assert back["solutions"][0]["reason"] == 'a "quoted" [1,2,3] text'


def test_the_default_sizes_read_a_plan_the_same(tmp_path: Path) -> None:
    path = written(plan_doc(3000), tmp_path)
    assert same(read_plan(path), path.read_text())


HOSTILE = {
    "ragged rows": '{"trajectory": {"t": [0, 1], "q": {"a": [[1, 2, 3], [4, 5], [6, 7, 8]]}}}',
    "deeper rows": '{"x": [[[1, 2], [3, 4]], [[5, 6], [7, 8]]], "y": [1]}',
    "NaN": '{"trajectory": {"t": [0.5, NaN, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 9.5]}}',
    "huge int": '{"order": [1, 2, 99999999999999999999999, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13]}',
    "empty rows": '{"trajectory": {"q": {"a": [[], [], [], [], [], [], [], [], [], [], []]}}}',
    "a string like a hole": '{"s": "\\u0000plan-array-0", "v": [1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 9.5]}',
    "a hole spelt with escapes": '{"s": "\\u0000\\u0070lan-array-0", "v": [1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5]}',
    "a hole out of range": '{"trajectory": {"t": "\\u0000plan-array-5"}, "v": [1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5]}',
    "a hole not a number": '{"trajectory": {"t": "\\u0000plan-array-x"}, "v": [1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5]}',
    "a table taking another's hole": '{"trajectory": {"t": "\\u0000plan-array-0", "q": {"a": [[1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5]]}}}',
    "brackets in strings": '{"s": "[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14]", "e": "\\"[1,2]"}',
    "spaces everywhere": '{"trajectory": {"t": [ 0 , 1.0 ,\n 2e0 , -3.5E-1 , 4 , 5 , 6 , 7 , 8 , 9 ] } }',
}  # fmt: skip


@pytest.mark.parametrize("name", list(HOSTILE))
def test_odd_but_valid_json_reads_as_json_reads_it(small_windows: None, tmp_path: Path,
                                                   name: str) -> None:  # fmt: skip
    path = tmp_path / "plan.json"
    path.write_text(HOSTILE[name])
    assert same(read_plan(path), path.read_text())


BROKEN = {
    "double comma": '{"trajectory": {"t": [0.0, 1.0,, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]}}',
    "trailing comma": '{"trajectory": {"t": [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0,]}}',
    "two dots": '{"trajectory": {"t": [0.0, 1..0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]}}',
    "missing comma between rows": '{"trajectory": {"q": {"a": [[1.0, 2.0] [3.0, 4.0], [5.0, 6.0], [7.0, 8.0]]}}}',
    "unclosed": '{"trajectory": {"t": [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0}}',
    "cut off": '{"trajectory": {"t": [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]',
    "empty": "",
}  # fmt: skip


@pytest.mark.parametrize("name", list(BROKEN))
def test_broken_json_is_refused_as_json_refuses_it(small_windows: None, tmp_path: Path,
                                                   name: str) -> None:  # fmt: skip
    path = tmp_path / "plan.json"
    path.write_text(BROKEN[name])
    with pytest.raises(json.JSONDecodeError):
        json.loads(path.read_text())
    with pytest.raises(ValueError):
        read_plan(path)


def test_a_non_finite_table_value_is_not_written() -> None:
    doc = plan_doc(10)
    doc["trajectory"]["qd"]["arm0"][3, 2] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        write_plan(doc, io.StringIO())
