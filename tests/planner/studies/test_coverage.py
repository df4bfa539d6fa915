"""Coverage: points whose reachability is known, and reported relays re-traced."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.model.system import System
from planner.studies import coverage as cov
from planner.studies import coverage_safety as cs
from planner.studies.relay_geometry import chain_system, solve_chain


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
        for hits, d, _ in cov.reach_target(full, chain, p, n)[:3]:
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
        {"N": 1, "point": 0, "chain": "0", "reached": 1, "azimuths_deg": ""},
        {"N": 1, "point": 1, "chain": "0", "reached": 0, "azimuths_deg": ""},
        {"N": 2, "point": 0, "chain": "0", "reached": 1, "azimuths_deg": ""},
        {"N": 2, "point": 2, "chain": "0-1", "reached": 1, "azimuths_deg": "125.0 95.0"},
        {"N": 2, "point": 1, "chain": "1", "reached": 0, "reached_geometric": 1,
         "broken": "arm_self; beam_arm (parked)", "azimuths_deg": ""},
        {"N": 3, "point": 1, "chain": "2", "reached": 0, "reached_geometric": 1,
         "broken": "arm_arm (parked)", "azimuths_deg": ""},
    ]  # fmt: skip
    rows = [{"reached_geometric": r["reached"], "broken": "", **r} for r in rows]
    s = cov.summarize(points, rows)
    assert [x["points_reached"] for x in s] == [1, 2, 0]
    assert [x["points_geometric"] for x in s] == [1, 3, 1]
    assert [x["rules_broken"] for x in s] == [
        "-",
        "arm_self; beam_arm (parked)",
        "arm_arm (parked)",
    ]
    assert [x["sectors_reached"] for x in s] == [0, 2, 0]


# --- the safety rules ------------------------------------------------------------------------
def _min_distance(world, parts, geom, tf) -> float:
    """Smallest coal distance (m) from ``geom`` at ``tf`` to the world's ``parts``."""
    import coal

    out = np.inf
    for p in parts:
        res = coal.DistanceResult()
        coal.distance(geom, tf, world.geometry(p.index), world.placement(p.index),
                      coal.DistanceRequest(), res)  # fmt: skip
        out = min(out, res.min_distance)
    return out


def test_parked_arms_keep_the_product_arm_arm_clearance() -> None:
    """Robot 0 alone in the beam, robots 1 and 2 parked: the distance the chain's rules see
    between robot 0 and the parked arms is the product's own arm-arm distance of the whole
    cell at the same joints (capsule against capsule, no conversion)."""
    from planner.safety import PairKind, SafetyWorld, pair_clearances

    full = cov.coverage_system(3)
    rules = cov._rules(3, (0,))
    world = SafetyWorld(full, bare=True)
    rng = np.random.default_rng(2)
    home = full.robots[0].home
    for _ in range(30):
        q0 = home + rng.uniform(-1.5, 1.5, 6) * np.array([1.5, 1, 1, 1, 1, 1])
        q = full.stack_q([q0, *(cs.parked_q(r) for r in full.robots[1:])])
        ref = min(c.distance for c in pair_clearances(world, q, (PairKind.ARM_ARM,))
                  if "arm0/" in c.a + c.b and "arm0/base" not in (c.a, c.b))  # fmt: skip
        mine = min(c.distance for c in pair_clearances(rules.safety.world, q0,
                   (PairKind.ARM_SCENE,)) if "parked" in c.b)  # fmt: skip
        if ref > 0:
            assert mine == pytest.approx(ref, abs=1e-6)
        else:
            assert mine <= 1e-9


def test_the_beam_keeps_the_clearance_from_parked_arms() -> None:
    """Beam segments near the parked arms: flagged whenever a segment passes closer than the
    clearance to a parked part (coal on the original parts), never beyond sqrt(3) x it (a
    grown box's corners)."""
    import coal

    from planner.safety import DEFAULT_CLEARANCE, SafetyWorld
    from planner.safety.geometry import PartKind

    full = cov.coverage_system(3)
    rules = cov._rules(3, (0,))
    world = SafetyWorld(full, bare=True)
    world.update(full.stack_q([full.robots[0].home, *(cs.parked_q(r) for r in full.robots[1:])]))
    parked = [p for p in world.parts if p.robot in (1, 2) and p.kind is not PartKind.SCENE]
    centres = np.array([world.placement(p.index).getTranslation() for p in parked])
    rng = np.random.default_rng(5)
    laser = full.world_T_laser[:3, 3]
    flagged = clear = 0
    for _ in range(300):
        a = centres[rng.integers(len(centres))] + rng.normal(0, 0.06, 3)
        b = a + rng.normal(0, 0.2, 3)
        L = float(np.linalg.norm(b - a))
        R = np.linalg.qr(np.column_stack([(b - a) / L, rng.normal(size=(3, 2))]))[0]
        R = R[:, [1, 2, 0]] * np.array([1, 1, np.sign(R[:, 0] @ (b - a))])  # z along a -> b
        if np.linalg.det(R) < 0:
            R[:, 0] *= -1
        tf = coal.Transform3s(R, (a + b) / 2)
        d = _min_distance(world, parked, coal.Capsule(0.0, L), tf)
        v = rules.safety.geometry(np.array([laser, a, b]))  # laser -> a is far above them
        seen = v is not None and v.check.value == "beam_keep_out"
        if d < DEFAULT_CLEARANCE - 1e-6:
            assert seen, d
            flagged += 1
        elif d > np.sqrt(3) * DEFAULT_CLEARANCE:
            assert not seen or "laser->arm0" in v.text, (d, v)
            clear += 1
    assert flagged > 20 and clear > 20


def test_every_safe_relay_passes_the_whole_cells_checks() -> None:
    """Independent of the chain's rules: rebuild the whole three-robot cell with the chain's
    arms at the relay and the others parked; the product's arm checks on the whole cell
    (arm-arm with the parked arms, arm-self, arm-object) find nothing."""
    from planner.model.transforms import make_T
    from planner.safety import Safety, sphere

    full = cov.coverage_system(3)
    safety = Safety(full, [sphere("object", cov.RADIUS, make_T(p=cov.CENTER))])
    checked = 0
    for az, el in ((150, 20), (30, 40), (270, 10)):
        p, n = _point(az, el)
        for chain in cov._chains(3):
            sub = chain_system(full, chain.robots)
            for hits, _, bad in cov.reach_target(full, chain, p, n, cov._rules(3, chain.robots)):
                if bad is not None:
                    continue
                q_sub = sub.split_q(solve_chain(sub, list(hits), p, cov.SPINS))
                q = full.stack_q([q_sub.get(r.name, cs.parked_q(r)) for r in full.robots])
                assert safety.arms(q) is None
                checked += 1
    assert checked > 5
