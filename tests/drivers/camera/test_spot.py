"""Gated spot detection on rendered D435-like frames with the distractors of a real cell:
an e-stop button, a hand, skin, a saturated spot, a 1-2 px spot after YUYV -> RGB.

Each case also runs the old single-frame detector (brightest red blob) for comparison;
the figures (px, and mm at the paper_n1 camera distance) are printed with ``-s``.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.realsense import detect_red_spot
from drivers.camera.spot import GateHistory, SpotParams, detect_gated_spot, project
from planner.simcell.detectors import SPOT, frame, scene, spot_light, yuyv_roundtrip

FX, Z = 615.0, 0.87  # px, m: D435 colour focal length at 848 x 480, paper_n1 distance

CASES = {
    # name: (scene, e-stop, spot amplitude RGB, sigma px, yuyv, px tolerance, min confidence)
    "board, e-stop 426 px away": ("board", True, (120.0, 15.0, 10.0), 2.0, False, 0.1, 0.8),
    "skin, low contrast": ("skin", False, (25.0, 6.0, 4.0), 4.0, False, 0.5, 0.2),
    "saturated spot": ("board", False, (900.0, 600.0, 500.0), 3.0, False, 0.1, 0.8),
    "1-2 px spot after YUYV": ("board", False, (140.0, 10.0, 10.0), 0.6, True, 0.1, 0.5),
}


@pytest.mark.parametrize("name", list(CASES))
def test_gated_detection_finds_the_spot(name: str) -> None:
    kind, estop, amp, sigma, yuyv, tol, min_conf = CASES[name]
    rng = np.random.default_rng(7)
    base, light = scene(kind, estop), spot_light(amp, sigma)
    params = SpotParams(channel="luma" if yuyv else "red")
    conv = yuyv_roundtrip if yuyv else (lambda x: x)
    on = [conv(frame(base, light, rng)) for _ in range(2)]
    off = [conv(frame(base, None, rng)) for _ in range(2)]
    predicted = (SPOT[0] + 9.0, SPOT[1] - 6.0)  # the model's prediction, ~11 px off
    found = detect_gated_spot(on, off, predicted, params)
    assert found is not None and found.confidence > min_conf
    err = float(np.hypot(found.u - SPOT[0], found.v - SPOT[1]))
    whole = detect_gated_spot(on, off, None, params)  # without a prediction: same answer
    assert whole is not None and np.hypot(whole.u - found.u, whole.v - found.v) < 1e-6
    old = detect_red_spot(on[0])
    old_err = np.inf if old is None else float(np.hypot(*np.subtract(old[0], SPOT)))
    print(f"\n{name}: gated {err:.3f} px = {1e3 * err * Z / FX:.3f} mm at {Z} m, "
          f"confidence {found.confidence:.2f}; old detector {old_err:.1f} px "
          f"= {1e3 * old_err * Z / FX:.1f} mm")  # fmt: skip
    assert err <= tol
    assert old_err > 1.0  # the old detector is off by more than a pixel on every case


def test_no_spot_when_the_laser_is_dark() -> None:
    """A hand moves in, the laser is off (or disconnected): no spot, whatever is red."""
    rng = np.random.default_rng(3)
    base = scene("skin")
    on = [frame(base, None, rng) for _ in range(2)]  # gate on, but no light comes
    off = [frame(base, None, rng) for _ in range(2)]
    assert detect_gated_spot(on, off, SPOT) is None
    assert detect_gated_spot(on, off, None) is None
    assert detect_red_spot(on[0]) is not None  # the old detector reports the e-stop or hand
    with pytest.raises(ValueError, match="gate on and one with it off"):
        detect_gated_spot(on, [], SPOT)  # the gate never switched off: nothing to subtract


def test_spot_outside_the_window_is_not_taken() -> None:
    rng = np.random.default_rng(5)
    base = scene()
    on = [frame(base, spot_light((120.0, 15.0, 10.0), 2.0), rng)]
    off = [frame(base, None, rng)]
    far = (SPOT[0] - 200.0, SPOT[1])
    assert detect_gated_spot(on, off, far, SpotParams(radius=60.0)) is None
    assert detect_gated_spot(on, off, (np.nan, 0.0)) is None


def test_two_spots_lower_the_confidence() -> None:
    rng = np.random.default_rng(9)
    base = scene()
    light = spot_light((120.0, 15.0, 10.0), 2.0)
    light2 = np.roll(light, 30, axis=1) * 0.9  # a reflection 30 px to the right
    one = detect_gated_spot([frame(base, light, rng)], [frame(base, None, rng)], SPOT)
    two = detect_gated_spot([frame(base, light + light2, rng)], [frame(base, None, rng)], SPOT)
    assert one is not None and one.confidence > 0.9
    assert two is None or two.confidence < 0.2


def test_ir_frames_work_too() -> None:
    rng = np.random.default_rng(11)
    gray = scene()[..., 1]
    light = spot_light((80.0, 0, 0), 1.5)[..., 0]
    on = [frame(gray, light, rng)]
    off = [frame(gray, None, rng)]
    found = detect_gated_spot(on, off, SPOT)
    assert found is not None and np.hypot(found.u - SPOT[0], found.v - SPOT[1]) < 0.15


def test_project_matches_the_pinhole_model_and_refuses_points_behind() -> None:
    u, v = project(np.array([0.1, -0.05, 0.8]), 600.0, 601.0, 424.0, 240.0)
    assert (u, v) == pytest.approx((424.0 + 75.0, 240.0 - 601.0 * 0.0625))
    with pytest.raises(ValueError, match="behind"):
        project(np.array([0.0, 0.0, -1.0]), 600.0, 600.0, 0.0, 0.0)


def test_gate_history_classifies_exposures() -> None:
    g = GateHistory()
    assert g.state(0.0, 1.0) is None  # nothing known yet
    g.record(False, 10.0)
    g.record(True, 11.0)
    g.record(True, 11.5)  # repeated state: no new event
    g.record(False, 10.5)  # out of order: ignored
    assert g.events == [(10.0, False), (11.0, True)]
    assert g.state(10.2, 10.9) is False
    assert g.state(11.1, 11.2) is True
    assert g.state(10.9, 11.1) is None  # the gate switched during the exposure
