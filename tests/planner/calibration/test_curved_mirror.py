"""The beam calibration fits a mirror plane: with a curved mirror it refuses in one line
(the offline fit and its pose design raise, the online refit keeps the calibration in force
and says why), while a curved mirror earlier in the chain is traced as curved."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.calibration.beam import BeamData, beam_residual, calibrate_beam, plane_fit_refusal
from planner.calibration.collect import beam_plan
from planner.calibration.online import Calibration, refit
from planner.calibration.simulate import aim_chain
from planner.errors import InputError
from planner.model.mirror import FLAT
from planner.model.mirror_sphere import Sphere
from planner.model.system import System
from tests.planner.calibration.cal_systems import AIM, nominal_system, two_robot_system


def _curved(system: System, name: str) -> System:
    robots = tuple(replace(r, mirror=replace(r.mirror, surface=Sphere(0.4))) if r.name == name
                   else r for r in system.robots)  # fmt: skip
    return replace(system, robots=robots)


def test_the_plane_fit_refuses_a_curved_mirror() -> None:
    system = _curved(nominal_system(), "arm0")
    why = plane_fit_refusal(system, "arm0")
    assert why is not None and "\n" not in why and "Sphere(radius=0.4)" in why
    data = BeamData("arm0", np.zeros((20, 6)), np.zeros((20, 3)), np.zeros(20))
    with pytest.raises(InputError, match="fits a mirror plane; arm0's mirror is Sphere"):
        calibrate_beam(data, system)
    with pytest.raises(InputError, match="fits a mirror plane"):
        beam_plan(system, "arm0", 8, AIM, np.random.default_rng(0))
    result = refit([], Calibration(0, system), system)
    assert not result.accepted and result.reason == why
    assert result.calibration.system is system
    assert plane_fit_refusal(nominal_system(), "arm0") is None


def test_only_the_fitted_mirror_must_be_flat() -> None:
    """Calibrating arm1 behind a curved arm0: arm0's face is part of the traced chain (the
    residual of a spot the curved chain puts there is zero; the flat chain's is not)."""
    system = _curved(two_robot_system(), "arm0")
    assert plane_fit_refusal(system, "arm1") is None
    assert plane_fit_refusal(system, "arm0") is not None
    q = aim_chain(system, "arm1", AIM) + np.random.default_rng(1).uniform(-0.02, 0.02, system.nq)
    assert np.linalg.norm(BeamModel(system).trace(q).uv[0]) > 1e-3  # off arm0's vertex
    spot = BeamModel(system).trace(q).spot
    args = {"q": q, "d_laser": np.zeros(6), "d_mirror": np.zeros(6),
            "world_T_laser": system.world_T_laser,
            "world_T_base": np.hstack([r.world_T_base for r in system.robots]),
            "flange_T_mirror": np.hstack([r.mirror.flange_T_mirror for r in system.robots]),
            "spot": spot}  # fmt: skip
    curved = beam_residual(system.kinematics, system.surfaces)(**args)["r"]
    flat = beam_residual(system.kinematics, (FLAT, FLAT))(**args)["r"]
    assert np.linalg.norm(np.asarray(curved)) < 1e-12 < 1e-6 < np.linalg.norm(np.asarray(flat))
