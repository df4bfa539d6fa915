"""Coverage: points whose reachability is known, and reported relays re-traced."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.model.system import System
from planner.studies import coverage as cov
from planner.studies.relay_geometry import solve_chain


@pytest.fixture(scope="module")
def chains() -> tuple[cov.Chain, ...]:
    return cov._chains(3)


def _point(az_deg: float, el_deg: float) -> tuple[np.ndarray, np.ndarray]:
    a, e = np.deg2rad(az_deg), np.deg2rad(el_deg)
    n = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    return cov.CENTER + cov.RADIUS * n, n


def _reached(chains: tuple[cov.Chain, ...], p: np.ndarray, n: np.ndarray, n_robots: int) -> bool:
    system = cov.coverage_system(3)
    return any(cov.reach_target(system, c, p, n) for c in chains if max(c.robots) < n_robots)


def test_sub_chains_count() -> None:
    assert len(cov.sub_chains(3)) == 7  # 2^3 - 1 ordered subsets
    assert cov.sub_chains(2) == [(0,), (1,), (0, 1)]


def test_upper_cap_reached_by_one_robot(chains: tuple[cov.Chain, ...]) -> None:
    assert _reached(chains, *_point(0, 60), 1)


def test_top_pole_needs_a_second_robot(chains: tuple[cov.Chain, ...]) -> None:
    """Straight under the laser axis a single mirror would have to pass the beam on
    unchanged (v_out = v_in): impossible; a side robot lights it."""
    assert not _reached(chains, *_point(0, 90), 1)
    assert _reached(chains, *_point(0, 90), 2)


def test_bottom_pole_never_reached(chains: tuple[cov.Chain, ...]) -> None:
    """No mirror site is below the sphere within 60° of the downward normal."""
    for n in (1, 2, 3):
        assert not _reached(chains, *_point(0, -90), n)


def test_side_facing_robot_1_needs_two_robots(chains: tuple[cov.Chain, ...]) -> None:
    """With one robot the mirror is on the laser axis above the sphere: an equator point is
    hidden behind the sphere's own cap (segment from the axis grazes the surface)."""
    p, n = _point(120, 0)
    assert not _reached(chains, p, n, 1)
    assert _reached(chains, p, n, 2)


def test_reported_relays_retrace_exactly(chains: tuple[cov.Chain, ...]) -> None:
    """Independent check: rebuild each relay with solve_chain on the sub-chain's own system,
    trace it with the CasADi beam, and check incidence and occlusion analytically."""
    full = cov.coverage_system(3)
    p, n = _point(150, 20)
    checked = 0
    for chain in chains:
        sub = System(full.world_T_laser, tuple(full.robots[i] for i in chain.robots))
        for hits, d in cov.reach_target(full, chain, p, n)[:3]:
            q = solve_chain(sub, list(hits), p)
            assert q is not None
            tr = BeamModel(sub).trace(q, p, n)
            assert tr.error < 1e-9 and tr.valid
            assert tr.incidence <= cov.MAX_INCIDENCE + 1e-9
            assert np.allclose(tr.dirs[-1], d, atol=1e-9)
            pts = [full.world_T_laser[:3, 3], *hits, p]
            for a, b in itertools.pairwise(pts):  # segment vs sphere, analytic
                u = (b - a) / np.linalg.norm(b - a)
                s = np.clip((cov.CENTER - a) @ u, 0, np.linalg.norm(b - a) - 2e-3)
                assert np.linalg.norm(a + s * u - cov.CENTER) > cov.RADIUS - 1e-3
            checked += 1
    assert checked > 0


def test_summary_counts_a_known_set(chains: tuple[cov.Chain, ...]) -> None:
    points = np.array([_point(0, 90)[0], _point(0, -90)[0], _point(120, 0)[0]])
    rows = [
        {"point": 0, "chain": "0", "n_needed": 1, "reached": 1, "azimuths_deg": ""},
        {"point": 1, "chain": "0", "n_needed": 1, "reached": 0, "azimuths_deg": ""},
        {"point": 2, "chain": "0-1", "n_needed": 2, "reached": 1, "azimuths_deg": "125.0 95.0"},
    ]
    s = cov.summarize(points, rows)
    assert [x["points_reached"] for x in s] == [1, 2, 2]
    assert [x["sectors_reached"] for x in s] == [0, 2, 2]
