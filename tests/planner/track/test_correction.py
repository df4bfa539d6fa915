"""The camera-frame spot correction of tracking (:mod:`planner.track.correction`) on a small
system whose truth differs from the model: the camera 5 mm / 0.5 deg off its calibrated pose
and the laser 0.3 deg off. The camera "sees" the target and the spot through the true pose;
the true spot is the truth's beam on the true surface. Checked: the true error after the
correction (against the target as placed in the world), the measured error against the
camera-frame distance, the treatment's condition and every reason a spot is dropped."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.trace import trace_beam
from planner.ik import BeamIK
from planner.model.transforms import axis_angle_to_matrix, inv_T, look_at, make_T
from planner.track.correction import RESTART_AFTER, SpotCorrection
from schemas.scenario import Laser
from tests.planner.ik import ik_systems as sy

P = np.array([0.3, 0.3, 0.3])  # m: the true target (world)
CAL = look_at([0.3, 0.0, 1.1], P)  # the calibrated camera pose
AXIS = np.array([0.2, 0.9, -0.4]) / np.linalg.norm([0.2, 0.9, -0.4])
TRUE = CAL @ make_T(axis_angle_to_matrix(np.deg2rad(0.5) * AXIS), [0.003, -0.004, 0.0])
TILT = make_T(axis_angle_to_matrix(np.deg2rad(0.3) * np.array([0.0, 0.0, 1.0])), [0, 0, 0])


def cell() -> tuple[BeamIK, object, np.ndarray, np.ndarray, np.ndarray]:
    """The model's IK, the truth, the true surface normal and the target and normal as the
    calibrated camera pose maps what the true camera sees."""
    model = sy.n1()
    truth = sy.n1(sy.LASER @ TILT)
    ik = BeamIK(model)
    first = ik.solve(P)
    assert first.ok and first.q is not None
    tr = trace_beam(model, first.q, P)
    normal = -tr.dirs[-1] / np.linalg.norm(tr.dirs[-1])  # the surface faces the beam
    M = CAL @ inv_T(TRUE)  # what the camera saw, mapped through the calibrated pose
    return ik, truth, normal, M[:3, :3] @ P + M[:3, 3], M[:3, :3] @ normal


def seen(p_world: np.ndarray) -> np.ndarray:
    """A world point as the true camera sees it (optical frame)."""
    T = inv_T(TRUE)
    return np.asarray(T[:3, :3] @ p_world + T[:3, 3])


def step(c: SpotCorrection, ik: BeamIK, truth: object, normal: np.ndarray, p_map: np.ndarray,
         n_map: np.ndarray, t: float, q: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, str]:  # fmt: skip
    """One frame and one spot at time ``t``: aim at the corrected target, the truth's spot on
    the true surface seen by the true camera. (q, true spot, the spot's verdict)."""
    c.on_target(t, p_map, n_map)
    sol = ik.solve(c.corrected(p_map), n_map, q)
    assert sol.ok and sol.q is not None
    c.on_joints(t - 0.01, sol.q)
    c.on_joints(t + 0.01, sol.q)
    spot = trace_beam(truth, sol.q, P, normal).spot  # type: ignore[arg-type]
    return sol.q, spot, c.on_spot(t, seen(spot), 0.9)


def test_the_spot_converges_onto_the_target_the_camera_saw() -> None:
    ik, truth, normal, p_map, n_map = cell()
    c = SpotCorrection(ik.system, lambda q: CAL, tolerance=1e-3)
    assert not c.permits(0.0) and c.withheld == {"no_measurement": 1}  # nothing measured yet
    q, spot, why = step(c, ik, truth, normal, p_map, n_map, 0.0, None)
    open_loop = float(np.linalg.norm(spot - P))
    assert why == "used" and open_loop > 3e-3  # a real miscalibration
    # the measured delivery error is the camera-frame distance of spot and target
    assert c.error == pytest.approx(float(np.linalg.norm(seen(spot) - seen(P))), abs=1e-12)
    assert not c.permits(0.0) and c.withheld["over_tolerance"] == 1
    errors = []
    for k in range(1, 8):
        q, spot, why = step(c, ik, truth, normal, p_map, n_map, 0.05 * k, q)
        assert why == "used"
        errors.append(float(np.linalg.norm(spot - P)))
    print(f"true error: open loop {1e3 * open_loop:.2f} mm, then "
          f"{[round(1e3 * e, 4) for e in errors]} mm")  # fmt: skip
    assert errors[-1] < 1e-5
    assert c.error == pytest.approx(errors[-1], abs=1e-9)  # a rigid map keeps distances
    assert c.permits(0.35) and not c.permits(0.35 + c.fresh + 1e-6)  # a stale error: off
    fig = c.figures()
    assert fig["spots_used"] == 8 and fig["measured_error_first_mm"] == pytest.approx(
        1e3 * c.errors[0], abs=5e-4
    )


def test_spots_that_cannot_count_are_dropped_and_say_why() -> None:
    ik, truth, normal, p_map, n_map = cell()
    c = SpotCorrection(ik.system, lambda q: CAL)
    assert c.on_spot(0.0, None, 0.0) == "not_seen"
    assert c.on_spot(0.0, seen(P), 0.1) == "low_confidence"
    assert c.on_spot(0.0, seen(P), 0.9) == "no_joints"
    c.on_joints(-0.01, ik.system.home)
    c.on_joints(0.01, ik.system.home)
    assert c.on_spot(0.0, seen(P), 0.9) == "no_frame"
    q = None
    for k in range(4):
        q, _, why = step(c, ik, truth, normal, p_map, n_map, 0.1 + 0.05 * k, q)
        assert why == "used"
    assert c.permits(0.25)
    bias = c.bias.copy()
    # a bright point 10 mm from where the beam is: not the spot
    c.on_joints(0.30, q)
    c.on_target(0.30, p_map, n_map)
    side = np.cross(normal, [0, 0, 1.0])
    far = trace_beam(truth, q, P, normal).spot + 0.01 * side / np.linalg.norm(side)  # type: ignore[arg-type]
    for _ in range(RESTART_AFTER - 1):
        assert c.on_spot(0.30, seen(far), 0.9) == "implausible"
    np.testing.assert_array_equal(c.bias, bias)  # the estimate stands...
    assert not c.permits(0.30)  # ...but the camera contradicts it: no treatment
    assert c.on_spot(0.30, seen(far), 0.9) == "implausible"  # the 5th in a row: start again
    assert c.restarts == 1 and not c.permits(0.30) and np.all(c.bias == 0.0)
    c.on_target(0.31, np.full(3, np.nan), n_map)  # a frame the model has no beam for
    c.on_joints(0.32, q)
    assert c.on_spot(0.31, seen(far), 0.9) == "model_invalid"
    assert dict(c.dropped) == {"not_seen": 1, "low_confidence": 1, "no_joints": 1,
                               "no_frame": 1, "implausible": RESTART_AFTER,
                               "model_invalid": 1}  # fmt: skip


def test_no_treatment_on_a_stamp_from_the_future_or_a_bias_beyond_the_keep_out_padding() -> None:
    ik, truth, normal, p_map, n_map = cell()
    c = SpotCorrection(ik.system, lambda q: CAL, tolerance=1e-3)
    q = None
    for k in range(8):
        q, _, _ = step(c, ik, truth, normal, p_map, n_map, 0.05 * k, q)
    assert c.permits(0.36) and c.permits(0.35 - 0.005)  # 5 ms ahead: one machine's clocks
    assert not c.permits(0.35 - 0.1)  # measured 0.1 s "after" now: a clock to distrust
    assert not c.permits(0.35 + c.fresh + 1e-3)  # too old
    bias = float(np.linalg.norm(c.bias))
    assert bias > 3e-3  # the model is mm off: the rules' beam misses the true one by that
    c.max_bias = bias - 1e-4
    assert not c.permits(0.36) and c.figures()["bias_over_limit"] is True
    c.max_bias = bias + 1e-4
    assert c.permits(0.36) and c.figures()["bias_over_limit"] is False
    # every refusal counted by why (the summary says why the treatment stayed off)
    assert c.figures()["treatment_withheld"] == {"ahead": 1, "stale": 1, "bias_over_limit": 1}


def test_a_moving_target_is_taken_at_the_spot_time() -> None:
    """The tracked point at the spot's capture time is linear between the frames around it
    (and moved on along the last two past the last one, by at most one frame interval): a
    spot exactly where the target was then measures 0."""
    ik, _, _, p_map, n_map = cell()
    c = SpotCorrection(ik.system, lambda q: CAL)
    q = ik.solve(p_map, n_map).q
    assert q is not None
    for t in (0.0, 0.3):
        c.on_joints(t, q)
    v = np.array([0.02, -0.01, 0.0])  # m/s
    c.on_target(0.0, p_map, n_map)
    c.on_target(0.1, p_map + 0.1 * v, n_map)
    for t in (0.04, 0.13):
        where = p_map + t * v
        spot = inv_T(CAL)[:3, :3] @ where + inv_T(CAL)[:3, 3]  # a camera with the model's pose
        c.used = 0  # each its own first spot (no plausibility window)
        assert c.on_spot(t, spot, 0.9) == "used"
        assert c.error == pytest.approx(0.0, abs=1e-12)
    assert c.on_spot(0.25, spot, 0.9) == "no_frame"  # 0.15 s past the last frame


def test_the_correction_is_on_only_where_the_camera_can_see_the_beam() -> None:
    from types import SimpleNamespace

    from planner.service.track_start import camera_correction

    camera = SimpleNamespace(world_T_camera=CAL, robot=None)
    system = SimpleNamespace(camera=camera, world_T_camera=lambda q=None: CAL)
    on_arm = SimpleNamespace(camera=SimpleNamespace(robot="arm0"))
    gate, aim = {"robot": "arm0", "output": 0}, {"robot": "arm0", "output": 1}
    cases = [
        ("world", system, {}, "off: targets in the world frame"),
        ("camera", SimpleNamespace(camera=None), {}, "off: no camera"),
        ("camera", on_arm, {}, "off: the camera moves with an arm"),
        (
            "camera",
            system,
            {"gate": gate},
            "off: no aiming beam (laser.aim) to measure the spot with",
        ),
        ("camera", system, {"gate": gate, "aim": aim}, "on"),
        ("camera", system, {}, "on"),  # ungated (simulation): the laser is always on
    ]
    for frame, sys_, keys, why in cases:
        laser = Laser.model_validate({"world_T_laser": {}} | keys)
        c, said = camera_correction(SimpleNamespace(frame=frame), sys_, laser, 5e-4, 0.002)
        assert said == why and (c is not None) == (why == "on")
        if c is not None:
            assert c.tolerance == 5e-4 and c.world_T_camera is system.world_T_camera
            assert c.max_bias == 0.002


def test_a_corrected_session_takes_only_camera_frame_frames() -> None:
    """With the correction on, a stream frame in the world frame ends the session with a
    reason that says so: mapped spots against a true world point would add the camera's
    error, not remove it."""
    import json
    from types import SimpleNamespace

    from planner.bus.session import Keys
    from planner.service.track import TrackSession

    class Session:
        def declare_publisher(self, *a: object, **k: object) -> SimpleNamespace:
            return SimpleNamespace(put=lambda *a, **k: None, undeclare=lambda: None)

    ik, *_ = cell()
    system = SimpleNamespace(camera=SimpleNamespace(robot=None), robot_names=("arm0",),
                             world_T_camera=lambda q=None: CAL)  # fmt: skip
    stopped: list[str] = []
    follower = SimpleNamespace(first=P, markers=None, stop=stopped.append)
    corr = SpotCorrection(ik.system, lambda q: CAL)
    session = TrackSession(Session(), Keys("t"), "s", system, follower, "r",  # type: ignore[arg-type]
                           send_stop=lambda r: None, on_end=lambda s: None, correction=corr)  # fmt: skip

    class Payload(bytes):
        def to_bytes(self) -> bytes:
            return bytes(self)

    def frame(kind: str) -> SimpleNamespace:
        body = {"schema": "beamrelay.target_stream/1", "t": 1.0, "id": "r", "frame": kind,
                "points": [P.tolist()]}  # fmt: skip
        return SimpleNamespace(payload=Payload(json.dumps(body).encode()))

    session._on_sample(frame("camera"))
    assert session.ignored == 0 and session._slot is not None and not stopped
    session._on_sample(frame("world"))  # e.g. the shipped tracker, which sends world frames
    assert session.ignored == 1 and len(stopped) == 1
    assert "sends world-frame points but the request is in the camera frame" in stopped[0]
