"""``beamrelay plan`` and ``beamrelay check`` agree: one set of tolerances, and ``plan`` runs
the checks on the document it wrote (a 3-robot square path whose corners are marked sharp;
a path sample at 80.0000006 deg incidence)."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.verify.check import check_plan
from planner.verify.tolerances import INCIDENCE_SLACK, Tolerances

# Three UR5e relay the beam: laser -> arm0 -> arm1 -> arm2 -> a 40 mm square on the table
# (z = 0) centred at (-0.55, 0.25, 0). Homes: the closed-form UR5e inverse kinematics of the
# mirror poses whose normals bisect the incoming and outgoing beam through the mirror
# centres (-0.40, 0.05, 0.45), (-0.85, 0.15, 0.62), (-0.62, 0.62, 0.60) (incidences 62, 38,
# 33 deg); the laser at (-0.15, 0.35, 0.05) is aimed at arm0's mirror centre.
N3_SQUARE = """\
name: n3-square
system:
  laser:
    world_T_laser:
      xyz: [-0.15, 0.35, 0.05]
      quat: [-0.128385522, -0.354607221, 0.870841179, 0.315287992]
  robots:
    - name: arm0
      world_T_base: {xyz: [0, 0, 0]}
      home: [-0.252674, -1.793717, 2.222091, -3.045541, -2.253013, -2.791862]
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075], roi_margin: 0.005}
    - name: arm1
      world_T_base: {xyz: [-1.2, 0, 0], rpy_deg: [0, 0, 180]}
      home: [-0.177445, -2.070702, 2.016663, -2.780423, -0.942974, 2.957405]
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075], roi_margin: 0.005}
    - name: arm2
      world_T_base: {xyz: [-0.6, 1.1, 0], rpy_deg: [0, 0, -90]}
      home: [0.386145, -2.675273, 1.049718, 1.027477, -1.036426, 0.333996]
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075], roi_margin: 0.005}
targets:
  path:
    points: [[-0.57, 0.23, 0.0], [-0.53, 0.23, 0.0], [-0.53, 0.27, 0.0], [-0.57, 0.27, 0.0]]
    closed: true
    spacing: 0.002
trajectory: {spot_speed: 0.02, rate: 500}
"""

# The curve_path layout (one UR5e, the beam arrives ~40 deg off the board normal); a 60 mm
# line whose normals are tilted 62 deg further, so the 80 deg incidence limit binds along it.
INCIDENCE = """\
name: incidence-limit
system:
  laser: {world_T_laser: {xyz: [-0.491899, 0.188094, 0.074878], rpy_deg: [40, 0, 0]}}
  robots:
    - name: arm0
      home: [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075], roi_margin: 0.005}
targets:
  path:
    points: [[-0.52, -0.57, -0.06], [-0.46, -0.57, -0.06]]
    normals: [[0, -0.882948, 0.469472], [0, -0.882948, 0.469472]]
    spacing: 0.002
solver: {max_incidence_deg: 80}
trajectory: {spot_speed: 0.02, rate: 500}
"""


def beamrelay(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=600)  # fmt: skip


def test_three_robot_square_corners_marked_sharp(tmp_path: Path) -> None:
    # the square turns by 90 deg at each vertex (> corner_deg 20): four strokes, each marked
    # at constant speed with the laser off at the vertices; before, the joint spline swept
    # the corners continuously and cut them by 0.18 mm on the table
    scn, out = tmp_path / "n3.yaml", tmp_path / "n3.json"
    scn.write_text(N3_SQUARE)
    planned = beamrelay("plan", scn, "-o", out)
    assert planned.returncode == 0, planned.stdout + planned.stderr
    doc = json.loads(out.read_text())
    assert doc["robots"] == ["arm0", "arm1", "arm2"]
    assert doc["metrics"]["n_ok"] == doc["metrics"]["n_targets"] >= 80  # every sample solved
    checked = beamrelay("check", out, "--json")
    assert checked.returncode == 0, checked.stdout
    figures = json.loads(checked.stdout.strip().splitlines()[-1])
    assert figures["violations"] == 0
    dev = figures["trajectory spot.path_deviation_max_m"]  # the same figure from both
    assert dev == pytest.approx(doc["metrics"]["extra"]["path_deviation_max"], abs=1e-9)
    assert dev <= 5e-5 and figures["laser.polyline_deviation_max_m"] <= 5e-5
    assert "check of the plan: OK" in " ".join(planned.stdout.split())
    traj = doc["trajectory"]
    assert len(traj["laser_on"]) == 4
    # the spot traced onto the table plane z = 0: on the square's edges within the tolerance
    # at every laser-on sample, and at the first and last laser-on sample of each stroke
    # within a servo step (20 mm/s / 500 Hz = 0.04 mm) of a vertex
    from planner.verify.trajectory import trace_last_ray

    corners = np.array([[-0.57, 0.23, 0], [-0.53, 0.23, 0], [-0.53, 0.27, 0], [-0.57, 0.27, 0]])
    for t0, t1 in traj["laser_on"]:
        i0, i1 = round(t0 * 500), round(t1 * 500)
        p, v = trace_last_ray(doc["scenario"], {r: np.asarray(q)[i0 : i1 + 1]
                                                for r, q in traj["q"].items()})  # fmt: skip
        spot = p - (p[:, 2] / v[:, 2])[:, None] * v
        a, b = corners, np.roll(corners, -1, axis=0)
        u = np.clip(np.einsum("mkj,kj->mk", spot[:, None] - a, b - a) / 0.04**2, 0, 1)
        off = np.linalg.norm(spot[:, None] - (a + u[..., None] * (b - a)), axis=2).min(axis=1)
        assert off.max() < 5e-5
        for end in (spot[0], spot[-1]):
            assert np.linalg.norm(corners - end, axis=1).min() < 4.1e-5


def test_incidence_at_the_limit_agrees(tmp_path: Path) -> None:
    scn, out = tmp_path / "inc.yaml", tmp_path / "inc.json"
    scn.write_text(INCIDENCE)
    planned = beamrelay("plan", scn, "-o", out)
    assert "Traceback" not in planned.stderr
    doc = json.loads(out.read_text())
    inc = np.array([s["incidence"] for s in doc["solutions"] if s["status"] == "ok"])
    assert len(inc) > 0
    # the solver lands a hair beyond the limit (80.0000006 deg): within the shared slack,
    # so the planner's ok is the checker's ok
    limit = np.radians(80.0)
    assert inc.max() > limit and inc.max() <= limit + INCIDENCE_SLACK
    checked = beamrelay("check", out, "--json")
    assert checked.returncode == 0, checked.stdout
    assert "check of the plan: OK" in planned.stdout
    assert json.loads(checked.stdout.strip().splitlines()[-1])["violations"] == 0
    # plan exits 1 only for the unsolved samples, which it reports
    unsolved = doc["metrics"]["n_targets"] - doc["metrics"]["n_ok"]
    assert planned.returncode == (1 if unsolved else 0)

    # beyond the slack both reject, the same targets: the checker, and planning's verdict
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.plan.document import verify_solutions

    tight = copy.deepcopy(doc)
    over = float(np.degrees(inc.max() - 2 * INCIDENCE_SLACK))
    tight["scenario"]["solver"]["max_incidence_deg"] = over
    flagged = {f.target for r in check_plan(tight) for f in r.findings if "incidence" in f.message}
    expected = {s["target"] for s in doc["solutions"]
                if s["status"] == "ok" and s["incidence"] > np.radians(over) + INCIDENCE_SLACK}  # fmt: skip
    assert flagged == expected and flagged
    loaded = load_scenario(scn)
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    from planner.ik import Solution

    sols = []
    for s in doc["solutions"]:
        q = None if s["status"] != "ok" else system.stack_q(s["q"])
        hits = None if q is None else np.array([h["p"] for h in s["hits"]])
        uv = None if q is None else np.array([h["uv"] for h in s["hits"]])
        spot = None if q is None else np.asarray(s["spot"])
        sols.append(Solution(s["status"], s["reason"], q, spot, s.get("error") or np.inf, hits,
                             uv, 0.0, 0, "path", s.get("incidence") or 0.0))  # fmt: skip
    verdict = verify_solutions(system, tight["scenario"], targets, sols)
    downgraded = {k for k, (a, b) in enumerate(zip(sols, verdict, strict=True)) if a.ok != b.ok}
    assert downgraded == flagged
    assert {verdict[k].reason for k in downgraded} == {"unreachable"}


def test_tolerances_boundaries() -> None:
    tol = Tolerances.from_scenario({"solver": {"tolerance": 1e-6, "max_incidence_deg": 80},
                                    "trajectory": {"path_tolerance": 1e-4, "rate": 250}})  # fmt: skip
    assert (tol.spot, tol.path, tol.rate) == (1e-6, 1e-4, 250.0)
    limit = np.radians(80.0)
    assert tol.incidence_ok(limit + INCIDENCE_SLACK)
    assert not tol.incidence_ok(limit + INCIDENCE_SLACK * 1.01)
    assert tol.min_cos_incidence == pytest.approx(np.cos(limit + INCIDENCE_SLACK), abs=0)
    assert tol.spot_ok(1e-6) and not tol.spot_ok(1.0000001e-6)
    default = Tolerances.from_scenario({})
    assert (default.spot, default.path, default.rate) == (1e-9, 5e-5, 500.0)


def test_path_validity_uses_the_checker_incidence_bound() -> None:
    from planner.path.nlp import PathOptions, constraint_lower_bounds
    from planner.path.warm import validity_bounds

    opts = PathOptions(max_incidence_deg=80.0)
    lbh = constraint_lower_bounds(2, 3, np.array([1.0, 0.0, 1.0]), opts)
    valid = validity_bounds(lbh, opts)
    cos_min = Tolerances(max_incidence=np.radians(80.0)).min_cos_incidence
    assert valid[0, -1] == cos_min and valid[2, -1] == cos_min
    assert valid[1, -1] == -np.inf  # no normal: no incidence bound
    assert np.all(valid[:, :-1] < lbh[:, :-1])  # the design margins, less a small slack
