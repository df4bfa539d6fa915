"""Study runtime: identical results whatever the executor (local, processes, Dask)."""

from __future__ import annotations

import numpy as np
import pytest

from planner.errors import InputError
from planner.studies import runtime
from planner.studies import sensitivity as sens


def _square_plus(x: int, seed: int) -> float:
    return float(x * x + np.random.default_rng([seed, x]).uniform())


def test_process_pool_keeps_order_and_values() -> None:
    jobs = [(i, 5) for i in range(7)]
    expected = [_square_plus(*j) for j in jobs]
    assert runtime.parallel_map(_square_plus, jobs, workers=2) == expected
    assert runtime.parallel_map(_square_plus, jobs, workers=1) == expected


def test_bad_workers_is_an_input_error() -> None:
    with pytest.raises(InputError):
        runtime.parallel_map(_square_plus, [(1, 0), (2, 0)], workers=0)


def test_dask_local_cluster_gives_identical_study_results() -> None:
    from dask.distributed import LocalCluster

    _, local = sens.run(trials=2, seed=3, workers=1)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False) as cluster:
        _, remote = sens.run(trials=2, seed=3, scheduler=cluster.scheduler_address)
    assert [r["error_mm"] for r in remote] == [r["error_mm"] for r in local]
    assert [r["predicted_mm"] for r in remote] == [r["predicted_mm"] for r in local]
