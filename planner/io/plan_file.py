"""plan.json text: written in bounded chunks so that a dense trajectory of millions of
samples adds little memory beyond the text itself."""

from __future__ import annotations

from typing import Any, TextIO

import numpy as np


def write_plan(doc: dict[str, Any], out: TextIO, digits: int = 10, chunk: int = 50_000) -> None:
    """Write plan.json text to ``out``: indented, but the dense ``trajectory`` rows written
    compactly with times, joints and their derivatives rounded to ``digits`` decimals
    (1e-10 rad by default; solutions keep full precision). Rows are formatted ``chunk`` at
    a time, so the extra memory does not grow with the trajectory."""
    import json

    traj = doc.get("trajectory")
    if not traj:
        out.write(json.dumps(doc, indent=1))
        return

    def rows(x: Any) -> None:
        out.write("[")
        for i in range(0, len(x), chunk):
            part = np.round(np.asarray(x[i : i + chunk], dtype=float), digits).tolist()
            out.write(("," if i else "") + json.dumps(part, separators=(",", ":"))[1:-1])
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
