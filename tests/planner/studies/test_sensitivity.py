"""Sensitivity study: CasADi first-order prediction vs sampled errors, seeding, executors."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.studies import sensitivity as sens


@pytest.fixture(scope="module")
def nominal() -> sens.Nominal:
    return sens.solve_nominal(sens.default_system(), sens.grid_targets(n=2))


def test_nominal_is_exact(nominal: sens.Nominal) -> None:
    """BeamIK's closed-form member: spot on the target, hit at the mirror centre (the
    mirror sweep's lever-arm laws rotate the mount about that point), within limits."""
    assert nominal.solved.all()
    model = BeamModel(nominal.system)
    for q, t in zip(nominal.q, nominal.targets, strict=True):
        tr = model.trace(q, t)
        assert tr.error < 1e-9 and tr.valid
        assert np.all(tr.uv == pytest.approx(0.0, abs=1e-9))
        assert np.all(q >= nominal.system.lower) and np.all(q <= nominal.system.upper)


def test_jacobian_matches_finite_differences(nominal: sens.Nominal) -> None:
    """Columns of J against central differences of perturb() + trace (independent path)."""
    h = 1e-6
    k = 3
    for group in sens.GROUPS:
        cols = nominal.J[k][:, sens.GROUP_COLUMNS[group]]
        for j in range(3):
            d = np.zeros(3)
            d[j] = h
            plus = BeamModel(sens.perturb(nominal.system, group, d)).trace(
                nominal.q[k], nominal.targets[k]
            )
            minus = BeamModel(sens.perturb(nominal.system, group, -d)).trace(
                nominal.q[k], nominal.targets[k]
            )
            fd = (plus.residual - minus.residual) / (2 * h)
            assert np.allclose(fd, cols[:, j], atol=1e-6), (group, j)


def test_prediction_matches_samples_at_tiny_levels(
    nominal: sens.Nominal, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sens, "ROT_LEVELS_DEG", (1e-4,))
    monkeypatch.setattr(sens, "POS_LEVELS_MM", (1e-3,))
    rows = sens.trial_rows(nominal, 0, 7)
    e = np.array([r["error_mm"] for r in rows])
    p = np.array([r["predicted_mm"] for r in rows])
    assert len(rows) == 4 * len(nominal.targets)
    assert np.all(e > 0)
    assert np.allclose(p, e, rtol=1e-4)


def test_mirror_position_error_is_exactly_linear(nominal: sens.Nominal) -> None:
    """A mount shift moves the last ray parallel to itself: |J δ| is exact at any size."""
    rows = sens.trial_rows(nominal, 1, 3)
    sel = [r for r in rows if r["group"] == "mirror_pos"]
    assert sel
    for r in sel:
        assert r["error_mm"] == pytest.approx(r["predicted_mm"], abs=1e-9)


def test_predicted_rms_formula(nominal: sens.Nominal) -> None:
    """level·‖J‖_F/√3 against a Monte Carlo of |J δ| with many draws."""
    rng = np.random.default_rng(0)
    J = nominal.J[:, :, sens.GROUP_COLUMNS["laser_rot"]]
    lvl = sens.level_si("laser_rot", 0.5)
    d = rng.uniform(-1, 1, (20000, 3)) * lvl
    mc = np.sqrt(np.mean([np.sum((J[k] @ d.T) ** 2, axis=0).mean() for k in range(len(J))]))
    assert sens.predicted_rms_mm(nominal, "laser_rot", 0.5) == pytest.approx(1000 * mc, rel=0.02)


def test_trials_are_seeded(nominal: sens.Nominal) -> None:
    a = sens.trial_rows(nominal, 2, 11)
    b = sens.trial_rows(nominal, 2, 11)
    c = sens.trial_rows(nominal, 2, 12)
    assert [r["error_mm"] for r in a] == [r["error_mm"] for r in b]
    assert [r["error_mm"] for r in a] != [r["error_mm"] for r in c]
