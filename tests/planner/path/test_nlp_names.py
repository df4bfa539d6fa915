"""The path NLP's inputs come from ChainSymbols by name: packed and unpacked by name."""

from __future__ import annotations

import numpy as np

from planner.beam.graph import ChainSymbols, beam_function, system_params
from planner.path.nlp import PATH_PARAMETERS, SAMPLE_INPUTS, pack_params, sample_function
from tests.conftest import make_system


def test_sample_inputs_are_the_chain_symbols_by_name() -> None:
    system = make_system(2)
    chain = system.kinematics, system.surfaces
    f = sample_function(*chain)
    assert tuple(f.name_in()) == SAMPLE_INPUTS
    assert tuple(f.name_in())[: len(ChainSymbols._fields)] == ChainSymbols._fields
    assert set(system_params(system)) == set(ChainSymbols._fields) - {"q"}
    assert set(system_params(system)) < set(beam_function(*chain).name_in())


def test_pack_params_places_every_value_under_its_name() -> None:
    system = make_system(2)
    K, nq = 3, system.nq
    rng = np.random.default_rng(0)
    values = system_params(system) | {
        "target": rng.normal(size=(K, 3)), "nbar": rng.normal(size=(K, 3)),
        "has_normal": np.array([1.0, 0.0, 1.0]), "tangents": rng.normal(size=(3, 2 * K)),
        "q_ref": rng.normal(size=(K, nq)), "weights": rng.normal(size=5),
    }  # fmt: skip
    p = pack_params(system, values["target"], values["nbar"], values["has_normal"],
                    values["tangents"], values["q_ref"], values["weights"])  # fmt: skip
    # the NLP stores K-sample data with samples as columns
    as_stored = {"target": values["target"].T, "nbar": values["nbar"].T, "q_ref": values["q_ref"].T}
    i = 0
    for name in PATH_PARAMETERS:
        x = np.asarray(as_stored.get(name, values[name]), dtype=float)
        x = x if x.ndim == 2 else x[None, :]
        np.testing.assert_array_equal(p[i : i + x.size], x.ravel(order="F"), err_msg=name)
        i += x.size
    assert i == len(p)
