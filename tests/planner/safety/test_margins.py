"""Safety margins (conventions section 4): keep-out and beam-vs-arm volumes are inflated by
``laser.beam_radius`` + 3 x the included calibration's spot uncertainty.

The case: on the paper's N = 1 layout, a keep-out sphere sits just behind the grid's centre
target, its surface 0.4 mm from it, on the far side from the mirror. Every beam that reaches
the target from the mirror's side ends 0.4 mm from the sphere (the target is the nearest
point of the segment), whatever IK family member carries it: accepted with no margin,
refused as ``keep_out`` with a 0.5 mm beam radius or a 0.2 mm calibration uncertainty
(margin 0.6 mm). The distances are checked with plain numpy point-segment geometry.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ruamel.yaml import YAML

from planner.ik import BeamIK, IKOptions
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.system import System
from planner.model.transforms import make_T
from planner.safety import sphere
from planner.safety.model import Safety, SafetySettings
from tests.paths import REPO

OPTS = IKOptions(max_incidence=np.radians(80))
TARGET = np.array([-0.492, -0.519, 0.0])  # the paper grid's centre
RADIUS = 0.01  # m, the keep-out sphere
GAP = 0.0004  # m, from the target to the sphere's surface


@pytest.fixture(scope="module")
def paper() -> System:
    return system_from_scenario(load_scenario(REPO / "scenarios" / "paper_n1.yaml"))


@pytest.fixture(scope="module")
def centre(paper: System) -> np.ndarray:
    """The sphere's centre: behind the target, away from the mirror."""
    sol = BeamIK(paper, OPTS).solve(TARGET)
    assert sol.ok and sol.hits is not None
    towards = (sol.hits[-1] - TARGET) / np.linalg.norm(sol.hits[-1] - TARGET)
    return TARGET - (RADIUS + GAP) * towards


def _segment_distance(c: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Plain numpy: distance (m) from point c to segment a-b."""
    d = b - a
    s = float(np.clip((c - a) @ d / (d @ d), 0.0, 1.0))
    return float(np.linalg.norm(c - (a + s * d)))


def _solve(paper: System, centre: np.ndarray, **kw: float) -> Any:
    eye = (sphere("eye", RADIUS, make_T(p=centre)),)
    return BeamIK(paper, OPTS, Safety(paper, keep_out=eye, settings=SafetySettings(**kw))).solve(
        TARGET
    )


def test_no_margin_accepts_a_beam_0_4_mm_from_the_sphere(paper: System, centre: np.ndarray) -> None:
    sol = _solve(paper, centre)
    assert sol.ok and sol.hits is not None and sol.spot is not None
    d = _segment_distance(centre, sol.hits[-1], sol.spot) - RADIUS
    assert d == pytest.approx(GAP, abs=1e-6)  # independent numpy distance


def test_a_half_millimetre_beam_radius_refuses_it_as_keep_out(
    paper: System, centre: np.ndarray
) -> None:
    sol = _solve(paper, centre, margin=0.0005)
    assert not sol.ok and sol.reason == "keep_out" and sol.q is None
    ev = sol.evidence
    assert ev["check"] == "beam_keep_out" and ev["b"] == "keep_out/eye"
    assert float(ev["required_m"]) == pytest.approx(0.0005)  # type: ignore[arg-type]
    assert float(ev["distance_m"]) == pytest.approx(GAP, abs=2e-5)  # type: ignore[arg-type]


def _scenario(tmp: Path, centre: np.ndarray, beam_radius: float, report: dict[str, Any]) -> Path:
    yaml = YAML(typ="safe", pure=True)
    data = yaml.load((REPO / "scenarios" / "paper_n1.yaml").read_text())
    data["system"]["laser"]["beam_radius"] = beam_radius
    data["keep_out"] = [{"name": "eye", "sphere": RADIUS,
                         "world_T_object": {"xyz": [float(x) for x in centre]}}]  # fmt: skip
    data["targets"] = {"frame": "world", "points": [[float(x) for x in TARGET]]}
    data["include"] = ["calibration.yaml"]
    with (tmp / "calibration.yaml").open("w") as fh:
        yaml.dump({"system": {}, "report": report}, fh)
    path = tmp / "scenario.yaml"
    with path.open("w") as fh:
        yaml.dump(data, fh)
    return path


@pytest.mark.parametrize(
    ("beam_radius", "report", "margin", "ok"),
    [
        (0.0, {"kind": "beam"}, 0.0, True),
        (0.0005, {"kind": "beam"}, 0.0005, False),
        (0.0, {"kind": "beam", "spot_uncertainty": 0.0002}, 0.0006, False),
        (0.0, {"kind": "beam", "spot_uncertainty": 0.0001}, 0.0003, True),
        # an older beam file without the key: the RMS of its residuals, hypot(mean, std)
        (0.0, {"kind": "beam", "residuals": {"mean": 0.00012, "std": 0.00016}}, 0.0006, False),
        (0.0, {"kind": "handeye", "residuals": {"mean": 0.001, "std": 0.001}}, 0.0, True),
    ],
)
def test_the_scenario_margin_comes_from_beam_radius_and_the_included_calibration(
    tmp_path: Path,
    paper: System,
    centre: np.ndarray,
    beam_radius: float,
    report: dict[str, Any],
    margin: float,
    ok: bool,
) -> None:
    scn = load_scenario(_scenario(tmp_path, centre, beam_radius, report))
    system = system_from_scenario(scn)
    rules = Safety.from_scenario(scn, system)
    assert rules.settings.margin == pytest.approx(margin, abs=1e-12)
    sol = BeamIK(system, OPTS, rules).solve(TARGET)
    assert sol.ok is ok and (ok or sol.reason == "keep_out")
    # the plan's resolved scenario echoes what the checker needs to recompute the margin
    echo = resolved_scenario_dict(scn)
    u = float(echo["safety"]["spot_uncertainty"])
    assert float(echo["system"]["laser"].get("beam_radius", 0.0)) + 3 * u == pytest.approx(
        margin, abs=1e-12
    )


def test_beam_calibration_reports_its_rms_spot_residual() -> None:
    from planner.calibration.report import spot_rms
    from schemas.calibration import report_spot_uncertainty

    r = np.array([0.001, 0.002, np.nan, 0.003])
    assert spot_rms(r) == pytest.approx(np.sqrt((1 + 4 + 9) / 3) * 1e-3)
    assert report_spot_uncertainty({"kind": "beam", "spot_uncertainty": 0.0007}) == 0.0007
    assert report_spot_uncertainty(None) == 0.0


def test_beam_vs_arm_clearance_grows_by_the_margin() -> None:
    two = system_from_scenario(load_scenario(REPO / "scenarios" / "n2_shared.yaml"))
    rules = Safety(two, settings=SafetySettings(clearance=0.01, margin=0.002))
    required = {round(info[3], 12) for info in rules.beam_pairs.pair_info}
    assert required == {0.002, 0.012}  # own parts: margin; other parts: clearance + margin
