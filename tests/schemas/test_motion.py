"""``motion:`` on scene objects: valid kinds load, mistakes are located one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import load_scenario, scenario_from_dict, scene_objects
from planner.io.validate import validate_file
from tests.paths import SCENARIOS

BASE = (SCENARIOS / "breathing.yaml").read_text()
SINE = "motion: {kind: sine, axis: [0, 0, 1], amplitude: 0.005, frequency: 0.25}"


def error(tmp_path: Path, motion: str) -> str:
    assert SINE in BASE
    path = tmp_path / "x.yaml"
    path.write_text(BASE.replace(SINE, motion))
    with pytest.raises(InputError) as info:
        validate_file(path)
    return str(info.value).replace(str(tmp_path) + "/", "")


def line_of_motion() -> int:
    return next(i for i, s in enumerate(BASE.splitlines(), 1) if s.strip().startswith("motion:"))


def test_shipped_breathing_scenario_loads_its_sine() -> None:
    scn = load_scenario(SCENARIOS / "breathing.yaml")
    (item,) = scene_objects(scn)
    assert item.motion is not None and item.motion.kind == "sine"
    np.testing.assert_allclose(item.motion.direction, [0, 0, 1])
    assert (item.motion.amplitude, item.motion.frequency) == (0.005, 0.25)


def test_linear_motion_loads_and_echoes_in_the_resolved_scenario(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(
        BASE.replace(SINE, "motion: {kind: linear, velocity: [0.02, 0, 0], duration: 2}")
    )
    scn = load_scenario(path)
    resolved = resolved_scenario_dict(scn)
    assert resolved["scene"][0]["motion"] == {
        "kind": "linear",
        "velocity": [0.02, 0.0, 0.0],
        "duration": 2.0,
    }
    again = scene_objects(scenario_from_dict(resolved))[0].motion
    assert again is not None and again.duration == 2.0


@pytest.mark.parametrize(
    ("motion", "key", "words"),
    [
        (
            "motion: {kind: sine, axis: [0, 0, 1], amplitude: 5, frequency: 0.25}",
            "amplitude",
            "millimetres?",
        ),
        (
            "motion: {kind: sine, axis: [0, 0, 1], amplitude: 0.005, frequency: 60}",
            "frequency",
            "Hz",
        ),
        (
            "motion: {kind: sine, axis: [0, 0, 0], amplitude: 0.005, frequency: 0.25}",
            "axis",
            "is zero",
        ),
        ("motion: {kind: sine, axis: [0, 1], amplitude: 0.005, frequency: 0.25}", "axis", "3"),
        (
            "motion: {kind: sine, axis: [0, 0, 1], amplitude: -0.005, frequency: 0.25}",
            "amplitude",
            "must be > 0",
        ),
        (
            "motion: {kind: sine, axis: [0, 0, 1], amplitude: .nan, frequency: 0.25}",
            "amplitude",
            "",
        ),
        ("motion: {kind: sine, axis: [0, 0, 1], frequency: 0.25}", "amplitude", "required"),
        (
            "motion: {kind: sine, axis: [0, 0, 1], amplitude: 0.005, frequency: 0.25, duration: 2}",
            "duration",
            "not a key of kind sine",
        ),
        ("motion: {kind: linear, velocity: [20, 0, 0], duration: 2}", "velocity", "mm/s?"),
        (
            "motion: {kind: linear, velocity: [0.02, 0, 0], duration: 2000}",
            "duration",
            "milliseconds?",
        ),
        ("motion: {kind: linear, velocity: [0, 0, 0], duration: 2}", "velocity", "is zero"),
        ("motion: {kind: spin, velocity: [0.02, 0, 0], duration: 2}", "kind", ""),
        ("motion: {kind: linear, velocity: [0.02, 0, 0], duration: 2, speed: 1}", "speed", ""),
    ],
)
def test_bad_motion_is_a_located_error(tmp_path: Path, motion: str, key: str, words: str) -> None:
    msg = error(tmp_path, motion)
    assert msg.startswith(f"x.yaml:{line_of_motion()} scene[0].motion.{key}"), msg
    assert words in msg
    assert "\n" not in msg
