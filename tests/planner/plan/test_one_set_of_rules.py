"""One set of rules: the same targets planned through every entry point (``beamrelay plan``,
the notebook API, the planner node's request handler, the console's request) get the same
statuses and reasons, and a target no scenario file could hold is refused by each.

The scenario is ``scenarios/face_keepout.yaml`` (a head, keep-out eyes): a point on the face
(ok), an eye's centre (keep_out), a point inside the head (occluded).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

import planner
from planner.bus.session import encode
from planner.console.targets import Mode, TargetList, build_request
from planner.errors import InputError
from planner.model.transforms import inv_T
from planner.service.handler import handler_from_scenario
from tests.cli_run import beamrelay
from tests.paths import SCENARIOS

FACE = [-0.4920, -0.4953, -0.0396]  # the scenario's own fourth target, on the face
EYE = [-0.4675, -0.5436, 0.0040]  # the left eye's centre (a keep-out sphere)
INSIDE = [-0.492, -0.58, -0.11]  # 40 mm inside the head sphere
POINTS = [FACE, EYE, INSIDE]
EXPECTED = [("ok", None), ("failed", "keep_out"), ("failed", "occluded")]


def scenario(tmp_path: Path, points: list[list[float]]) -> Path:
    doc = yaml.safe_load((SCENARIOS / "face_keepout.yaml").read_text())
    doc["targets"] = {"frame": "world", "points": points}
    path = tmp_path / "face.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def verdicts(solutions: list[dict]) -> list[tuple[str, str | None]]:  # type: ignore[type-arg]
    return [(s["status"], s["reason"]) for s in solutions]


def test_every_entry_point_plans_the_same_targets_alike(tmp_path: Path) -> None:
    path = scenario(tmp_path, POINTS)
    out = tmp_path / "plan.json"
    ran = beamrelay("plan", path, "--out", out)
    assert ran.returncode == 1, ran.stderr  # 1: some targets failed
    cli = verdicts(json.loads(out.read_text())["solutions"])
    solver = planner.solver(path)
    api, q = [], None
    for p in POINTS:
        sol = solver.solve(p, q_prev=q)
        q = sol.q if sol.q is not None else q
        api.append((str(sol.status), None if sol.reason is None else str(sol.reason)))
    handler = handler_from_scenario(path)
    body = {"schema": "beamrelay.request/1", "id": "r", "points": POINTS}
    node = verdicts(handler.plan(handler.parse(encode(body))).to_document()["solutions"])
    camera = handler.system.camera
    assert camera is not None
    picks = TargetList()
    for p in POINTS:
        picks = picks.add(np.asarray(p))
    req = build_request(picks, Mode.POINTS, camera_T_world=inv_T(camera.world_T_camera))
    console = verdicts(handler.plan(handler.parse(encode(req))).to_document()["solutions"])
    print(f"cli {cli}\napi {api}\nnode {node}\nconsole {console}")
    assert cli == api == node == console == EXPECTED


def test_a_target_in_millimetres_is_refused_by_every_entry_point(tmp_path: Path) -> None:
    mm = [1e3 * x for x in FACE]  # ~700 m away
    ran = beamrelay("plan", scenario(tmp_path, [mm]), "--out", tmp_path / "p.json")
    assert ran.returncode == 2 and "did you give millimetres?" in ran.stderr, ran.stderr
    path = scenario(tmp_path, [FACE])
    with pytest.raises(InputError, match="did you give millimetres"):
        planner.solver(path).solve(mm)
    handler = handler_from_scenario(path)
    with pytest.raises(InputError, match="did you give millimetres"):
        handler.parse(encode({"schema": "beamrelay.request/1", "id": "r", "points": [mm]}))
    for bad in ([float("nan"), 0.0, 0.0], [0.0, 0.0, -0.5]):  # not finite; behind the camera
        with pytest.raises(InputError):
            planner.solver(path).solve(bad, frame="camera")
    # within the message schema's 100 m, beyond a scenario file's 20 m; behind the camera
    far = [50.0, 0.0, 0.0]
    with pytest.raises(InputError, match="beyond 20 m: did you give millimetres"):
        planner.solver(path).solve(far)
    with pytest.raises(InputError, match="beyond 20 m: did you give millimetres"):
        handler.parse(encode({"schema": "beamrelay.request/1", "id": "r", "points": [far]}))
    behind = {"schema": "beamrelay.request/1", "id": "r", "frame": "camera",
              "points": [[0.0, 0.0, -0.5]]}  # fmt: skip
    with pytest.raises(InputError, match="not in front of the camera"):
        handler.parse(encode(behind))
