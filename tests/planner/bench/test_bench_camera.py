"""``beamrelay bench camera``: the camera pose errors it applies, and its JSON figures on one
target per case (in-process, CliRunner)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from planner.bench.servo_world import camera_error
from planner.cli.bench import app
from planner.model.transforms import rotation_angle


@pytest.mark.parametrize("mm, deg", [(2.0, 0.2), (10.0, 1.0)])
def test_the_camera_error_has_the_asked_size(mm: float, deg: float) -> None:
    E = camera_error(mm, deg, seed=3)
    assert np.linalg.norm(E[:3, 3]) == pytest.approx(1e-3 * mm, rel=1e-12)
    assert np.degrees(rotation_angle(E[:3, :3])) == pytest.approx(deg, rel=1e-9)


def test_bench_camera_closes_the_loop_on_what_the_camera_saw() -> None:
    out = CliRunner().invoke(app, ["camera", "--trials", "1", "--targets", "1", "--camera-only",
                                   "--json"])  # fmt: skip
    assert out.exit_code == 0, out.output
    doc = json.loads(out.output.strip().splitlines()[-1])
    cases = doc["cases"]
    assert doc["camera_only"] is True
    assert [(c["camera_mm"], c["camera_deg"]) for c in cases] == [(2, 0.2), (5, 0.5), (10, 1)]
    assert all(c["targets"] == c["converged"] == 1 for c in cases)
    # open loop: off by the camera error alone (1 deg at ~0.9 m is ~15 mm), growing with it
    assert 1e-3 < cases[0]["open_max_m"] < cases[2]["open_max_m"] < 30e-3
    assert all(c["closed_max_m"] <= 0.5e-3 for c in cases)
