"""The laser-on beam check with conservative advancement: coal measures few samples, the
first violation is still the one a sample-by-sample check finds (and the checker's
independent numpy geometry agrees), including one that falls between measured samples."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from planner.model.transforms import Array, make_T
from planner.safety import sphere
from planner.safety.model import Safety, Violation
from planner.safety.trajectory import check_beam_samples, trace_batch
from planner.verify.safety import beam_hits
from tests.planner.safety.numpy_rules import setup
from tests.planner.safety.worlds import UPRIGHT, single

RATE = 500.0
FAR = np.full((1, 3), 100.0)  # no target near any beam: every beam runs on 2 m


class Spy(Safety):
    """Records the configurations coal measured."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.measured: list[Array] = []
        self.configs: list[Array] = []

    def beam(self, q: Array, points: Array, *, apertures: bool = True) -> Violation | None:
        self.measured.append(np.array(q))
        return super().beam(q, points, apertures=apertures)

    def config(self, q: Array, points: Array | None = None) -> Violation | None:
        self.configs.append(np.array(q))
        return super().config(q, points)


def _sweep(rng: np.random.Generator, m: int = 400) -> Array:
    q0 = UPRIGHT + rng.normal(0.0, 0.4, 6)
    q1 = q0 + rng.normal(0.0, 0.6, 6)
    return np.asarray(q0 + np.linspace(0.0, 1.0, m)[:, None] * (q1 - q0))


def _polylines(rules: Safety, Q: Array) -> Array:
    pts, v = trace_batch(rules, Q)
    return np.concatenate([pts, (pts[:, -1] + 2.0 * v)[:, None]], axis=1)


def _dense_first(rules: Safety, Q: Array, P: Array) -> int | None:
    """The sample-by-sample reference: coal at every sample."""
    for m in range(len(Q)):
        if np.all(np.isfinite(P[m])) and rules.beam(Q[m], P[m], apertures=False) is not None:
            return m
    return None


def test_first_violation_matches_the_sample_by_sample_check() -> None:
    system = single()
    rng = np.random.default_rng(0)
    numpy_rules = setup(system)
    found, measured, samples = 0, 0, 0
    for _ in range(16):
        rules = Spy(system)
        Q = _sweep(rng)
        t = np.arange(len(Q)) / RATE
        bad, n, exact = check_beam_samples(rules, t, Q, np.ones(len(Q), dtype=bool), FAR)
        assert exact == len(rules.measured)
        P = _polylines(rules, Q)
        ref = _dense_first(rules, Q, P)
        assert rules.apertures_batch(P) is None  # only pair rules in these sweeps
        if ref is None:
            assert bad is None and n == len(Q)
            measured, samples = measured + exact, samples + len(Q)
            continue
        found += 1
        assert bad is not None and bad[0] == t[ref] and n == ref + 1
        assert bad[1].reason == "occluded" and bad[1].margin < 0
        # the independent geometry sees the beam touch the arm there, and not well before
        split = {"arm0": Q}
        rows = {h.row for h in beam_hits(numpy_rules, split, P[:, :, :])}
        assert rows & {ref - 1, ref, ref + 1}
        assert not [r for r in rows if r < ref - 1]
    assert found >= 3
    assert measured < samples / 5  # most clean samples were certified, not measured


def test_violation_between_measured_samples_is_caught() -> None:
    system = single()
    Q = _sweep(np.random.default_rng(2))
    t = np.arange(len(Q)) / RATE
    mask = np.ones(len(Q), dtype=bool)
    clean = Spy(system)
    assert check_beam_samples(clean, t, Q, mask, FAR)[0] is None
    measured = [int(np.flatnonzero(np.all(q == Q, axis=1))[0]) for q in clean.measured]
    gaps = np.diff(measured)
    assert gaps.max() >= 8
    i = int(np.argmax(gaps))
    m_star = measured[i] + int(gaps[i]) // 2  # deep between two measured samples
    P = _polylines(clean, Q)
    centre = P[m_star, -2] + 0.4 * (P[m_star, -1] - P[m_star, -2])  # on the last segment
    eye = sphere("eye", 1e-3, make_T(p=centre))
    rules = Spy(system, keep_out=[eye])
    bad, n, _ = check_beam_samples(rules, t, Q, mask, FAR)
    assert bad is not None and bad[1].reason == "keep_out"
    assert bad[1].evidence["b"] == "keep_out/eye"
    ref = _dense_first(rules, Q, P)
    assert ref is not None and measured[i] < ref <= m_star
    assert bad[0] == t[ref] and n == ref + 1
    # independent: the numpy segment-sphere distance first dips below the radius there
    A, B = P[:, -2], P[:, -1]
    s = np.clip(((centre - A) * (B - A)).sum(axis=1) / ((B - A) ** 2).sum(axis=1), 0.0, 1.0)
    d = np.linalg.norm(A + s[:, None] * (B - A) - centre, axis=1)
    assert int(np.flatnonzero(d < 1e-3)[0]) == ref


def test_dwell_and_laser_off_samples() -> None:
    """Repeated configurations count once; no laser-on sample: nothing measured."""
    system = single()
    Q = np.tile(_sweep(np.random.default_rng(1), 5), (1, 1)).repeat(10, axis=0)
    t = np.arange(len(Q)) / RATE
    rules = Spy(system)
    bad, n, exact = check_beam_samples(rules, t, Q, np.ones(len(Q), dtype=bool), FAR)
    assert bad is None and n == 5 and 1 <= exact <= 5
    assert check_beam_samples(rules, t, Q, np.zeros(len(Q), dtype=bool), FAR) == (None, 0, 0)


def test_configs_equal_config_row_by_row() -> None:
    """:func:`configs` (per-row rules with advancement) against ``Safety.config`` at every
    row: the same rows break a rule, with the same check, and coal measured few rows."""
    from planner.safety.beam_cover import configs

    system = single()
    rng = np.random.default_rng(0)
    broken, measured, rows = 0, 0, 0
    for _ in range(12):
        Q = _sweep(rng)
        rules = Spy(system)
        P = _polylines(rules, Q)
        got = configs(rules, Q, P)
        calls = len(rules.configs)
        ref = [rules.config(q, p) for q, p in zip(Q, P, strict=True)]
        assert [v is None for v in got] == [v is None for v in ref]
        assert [v.check for v in got if v] == [v.check for v in ref if v]
        broken += sum(v is not None for v in ref)
        clean = sum(v is None for v in ref)
        measured, rows = measured + calls - (len(Q) - clean), rows + clean
    assert broken > 0 and measured < rows / 4


def test_configs_of_non_finite_rows_raise_as_config() -> None:
    from planner.safety.beam_cover import configs

    system = single()
    Q = _sweep(np.random.default_rng(3), 5)
    P = _polylines(Safety(system), Q)
    P[2, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        configs(Safety(system), Q, P)
    assert configs(Safety(system), Q[:0], P[:0]) == []
