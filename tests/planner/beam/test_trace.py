"""One trace type, one validity rule: the CasADi graph and the numpy trace return the same
BeamTrace with the same ``valid``; ``beamrelay trace`` applies that rule."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.beam.trace import BeamTrace, trace_beam
from planner.model.validity import MIN_AHEAD, MIN_FRONT
from tests.conftest import make_system
from tests.paths import REPO


@pytest.mark.parametrize("n", [1, 2])
def test_graph_and_numpy_trace_agree(n: int) -> None:
    system = make_system(n, seed=5)
    model = BeamModel(system)
    rng = np.random.default_rng(n)
    verdicts = set()
    for _ in range(30):
        q = system.home + rng.uniform(-0.3, 0.3, system.nq)
        target = rng.uniform(-0.5, 0.5, 3)
        normal = None if rng.random() < 0.5 else _unit(rng.normal(size=3))
        a, b = model.trace(q, target, normal), trace_beam(system, q, target, normal)
        assert type(a) is type(b) is BeamTrace
        for name in ("spot", "hits", "uv", "dirs", "front", "ahead", "roi", "residual"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-9, err_msg=name)
        assert a.valid == b.valid
        verdicts.add(a.valid)
    assert n > 1 or verdicts == {True, False}  # N = 1: both outcomes exercised


def test_thresholds_are_the_rule() -> None:
    system = make_system(1)
    tr = trace_beam(system, system.home, np.zeros(3))
    tr = tr._replace(front=np.ones(1), ahead=np.ones(1), roi=np.full((1, 2), 0.01),
                     target_ahead=1.0)  # fmt: skip
    assert tr.valid
    assert not tr._replace(front=np.full(1, 0.5 * MIN_FRONT)).valid
    assert not tr._replace(ahead=np.full(1, 0.5 * MIN_AHEAD)).valid
    assert not tr._replace(target_ahead=0.5 * MIN_AHEAD).valid
    assert not tr._replace(roi=np.array([[0.01, -1e-12]])).valid
    assert tr._replace(roi=np.array([[0.01, 0.0]])).valid


def test_cli_trace_rejects_a_grazing_beam(tmp_path: Path) -> None:
    """A laser that meets the mirror centre at front = -n.v = 0.5e-9 (above 0, below the
    rule's threshold): ``beamrelay trace`` calls it a back-face hit, like the IK does."""
    from planner.io.scenario import load_scenario, system_from_scenario

    scn = REPO / "scenarios/paper_n1.yaml"
    system = system_from_scenario(load_scenario(scn))
    M = BeamModel(system).world_T_mirrors(system.home)[0]
    n, e, y = M[:3, 2], M[:3, 0], M[:3, 1]
    eps = 0.5 * MIN_FRONT
    v = -eps * n + np.sqrt(1 - eps**2) * e
    laser = np.eye(4)
    laser[:3, 0], laser[:3, 1], laser[:3, 2] = y, np.cross(v, y), v
    laser[:3, 3] = M[:3, 3] - 0.5 * v
    assert 0 < -(n @ laser[:3, 2]) < MIN_FRONT
    text = scn.read_text().splitlines()
    i = next(k for k, line in enumerate(text) if "world_T_laser" in line)
    text[i] = f"    world_T_laser: {{matrix: {laser.tolist()}}}"
    grazing = tmp_path / "grazing.yaml"
    grazing.write_text("\n".join(text) + "\n")
    proc = subprocess.run([sys.executable, "-m", "planner.cli", "trace", str(grazing)],
                          capture_output=True, text=True, cwd=REPO)  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "back face" in proc.stdout and "NOT valid" in proc.stdout
    assert not trace_beam(system_from_scenario(load_scenario(grazing)), system.home, M[:3, 3]).valid


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x)


def test_checker_applies_the_same_rule() -> None:
    """The independent checker (own FK, own mirror surface) judges each configuration as
    the planner's BeamTrace does: the same thresholds, with its rounding slack."""
    from planner.model.validity import ahead_ok, chain_ok, front_ok, roi_ok
    from planner.verify.context import ArmGeometry, spots, trace_arms
    from planner.verify.numpy_beam import ur5e_dh_fk
    from planner.verify.tolerances import ROI_SLACK, TRACE_SLACK

    system = make_system(1, seed=2)
    arms = [ArmGeometry(r.name, ur5e_dh_fk, r.world_T_base, r.mirror.flange_T_mirror,
                        r.mirror.roi_half, r.limits.lower, r.limits.upper)
            for r in system.robots]  # fmt: skip
    rng = np.random.default_rng(9)
    Q = system.home + rng.uniform(-0.1, 0.1, (200, system.nq))
    T = rng.uniform(-0.6, 0.6, (200, 3))
    rays = trace_arms(system.world_T_laser, arms, {"arm0": Q})
    _, s, _ = spots(rays.p, rays.v, T, np.full((200, 3), np.nan))
    margin = arms[0].roi_half - np.abs(rays.uv[0])
    checker = (front_ok(rays.front[0], TRACE_SLACK) & ahead_ok(rays.ahead[0], TRACE_SLACK)
               & roi_ok(margin, ROI_SLACK).all(axis=1) & ahead_ok(s, TRACE_SLACK))  # fmt: skip
    planner = np.array([trace_beam(system, q, t).valid for q, t in zip(Q, T, strict=True)])
    np.testing.assert_array_equal(checker, planner)
    assert 10 < planner.sum() < 190  # both verdicts represented
    assert chain_ok([1.0], [1.0], [[0.0, 0.0]], 1.0)
