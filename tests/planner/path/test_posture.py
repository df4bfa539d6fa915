"""Path posture: the path NLP keeps the arm near its home posture (the warm start is the
closed-form member nearest home, held by the reference term), far from the straight-elbow
singularity it used to settle in; the plan reports the Jacobian condition number."""

from __future__ import annotations

import numpy as np
import pytest

from planner.ik.closed_form import ClosedForm
from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
from planner.path.solve import jacobian_condition, plan_path
from planner.verify.numpy_beam import ur5e_dh_fk
from tests.paths import SCENARIOS


def _dh_condition(q: np.ndarray, h: float = 1e-6) -> float:
    """Condition number of the UR5e flange Jacobian by central differences of the numpy DH
    model (independent of Pinocchio): rows linear velocity and angular velocity."""
    J = np.zeros((6, 6))
    R0 = ur5e_dh_fk(q[None]).reshape(4, 4)[:3, :3]
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        Tp, Tm = (ur5e_dh_fk((q + s * dq)[None]).reshape(4, 4) for s in (1, -1))
        J[:3, j] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        W = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ R0.T
        J[3:, j] = [W[2, 1], W[0, 2], W[1, 0]]
    return float(np.linalg.cond(J))


@pytest.fixture(scope="module")
def circle(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """A 30 mm circle (48 vertices, smooth) centred where the home beam lands in the
    curve_path layout."""
    text = (SCENARIOS / "curve_path.yaml").read_text()
    head = text[: text.index("targets:")]
    c, r = np.array([-0.4918, -0.5679, -0.06]), 0.015
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    pts = ", ".join(f"[{c[0] + r * np.cos(x):.6f}, {c[1] + r * np.sin(x):.6f}, -0.06]" for x in a)
    f = tmp_path_factory.mktemp("c") / "circle.yaml"
    f.write_text(head + f"targets:\n  path: {{closed: true, smooth: true, spacing: 0.001, "
                 f"points: [{pts}], normals: [{', '.join(['[0, 0, 1]'] * 48)}]}}\n")  # fmt: skip
    loaded = load_scenario(f)
    system = system_from_scenario(loaded)
    return system, targets_from_scenario(loaded, system)


def test_circle_stays_near_home_and_well_conditioned(circle) -> None:  # type: ignore[no-untyped-def]
    system, targets = circle
    res = plan_path(system, targets, seeder=ClosedForm(system))
    assert res.ok.all()
    # before: the elbow went to -0.02 rad (straight arm), condition number ~600
    assert np.abs(res.q[:, 2] - system.home[2]).max() < 0.1
    assert np.abs(res.q - system.home).max() < 0.1
    cond = jacobian_condition(system, res.q)
    assert cond.max() < 20
    for k in (0, len(res.q) // 2):
        assert cond[k] == pytest.approx(_dh_condition(res.q[k]), rel=1e-4)


def test_plan_reports_the_condition_and_a_short_approach() -> None:
    from planner.plan.pipeline import run_scenario

    o = run_scenario(SCENARIOS / "curve_path.yaml", progress=False)
    x = o.doc["metrics"]["extra"]
    Q = np.array([s.q for s in o.solutions if s.q is not None])
    independent = max(_dh_condition(q) for q in Q[:: max(1, len(Q) // 20)])
    assert (
        independent <= x["jacobian_condition_max"] * (1 + 1e-4) and x["jacobian_condition_max"] < 20
    )
    # the approach from home is a fraction of the 151 mm mark (it took 1.27 s before)
    assert x["approach_time"] < 0.25 * x["path_time"]
