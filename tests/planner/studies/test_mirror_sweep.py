"""Mirror sweep: lever-arm laws checked against the traced beam."""

from __future__ import annotations

import numpy as np
import pytest

from planner.studies import mirror_sweep as ms
from planner.studies.sensitivity import default_system, solve_nominal


@pytest.fixture(scope="module")
def rows() -> list[dict]:
    nominal = solve_nominal(default_system(), ms.random_targets(3, seed=4))
    assert nominal.solved.all()
    return [r for k in range(3) for r in ms.sweep_target(nominal, k)]


def test_tilt_in_error_is_L_sin_2dtheta(rows: list[dict]) -> None:
    for r in (r for r in rows if r["axis"] == "tilt_in"):
        expected = 1000 * r["beam_length_m"] * abs(np.sin(2 * np.deg2rad(r["offset"])))
        assert r["error_mm"] == pytest.approx(expected, abs=1e-8)


def test_normal_shift_is_2dp_sin_i(rows: list[dict]) -> None:
    for r in (r for r in rows if r["axis"] == "normal"):
        sin_i = np.sqrt(1 - r["cos_incidence"] ** 2)
        assert r["error_mm"] == pytest.approx(2 * abs(r["offset"]) * sin_i, abs=1e-8)


def test_in_plane_moves_and_spin_do_nothing(rows: list[dict]) -> None:
    for r in (r for r in rows if r["axis"] in ("spin", "in_plane_a", "in_plane_b")):
        assert r["error_mm"] < 1e-8


def test_orientation_slope_is_two_L(rows: list[dict]) -> None:
    """Fitted slope of tilt_in (mm/deg) ≈ 2·L̄·π/180 (small-angle law), to 0.1 %."""
    table = {s["axis"]: s for s in ms.slopes(rows)}
    L = np.mean([r["beam_length_m"] for r in rows if r["axis"] == "tilt_in" and r["offset"] == 1.0])
    assert table["tilt_in"]["slope"] == pytest.approx(2 * L * np.pi / 180 * 1000, rel=1e-3)
    assert table["tilt_in"]["slope"] > 10 * table["normal"]["slope"]  # orientation dominates


def test_curves_carry_the_spread_over_targets(rows: list[dict]) -> None:
    """Fig. 5 bands: mean and standard deviation over the targets at each offset."""
    c = ms.curves(rows)
    at = [r["error_mm"] for r in rows if r["axis"] == "tilt_in" and r["offset"] == 1.0]
    i = int(np.flatnonzero(c["tilt_in"]["offset"] == 1.0)[0])
    assert c["tilt_in"]["error"][i] == pytest.approx(np.mean(at))
    assert c["tilt_in"]["std"][i] == pytest.approx(np.std(at)) and c["tilt_in"]["std"][i] > 0
    assert np.all(c["spin"]["std"] < 1e-8)
