"""Scene-object motion: offsets against closed forms, velocity against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from planner.model.motion import ObjectMotion


def test_sine_offset_is_the_closed_form() -> None:
    m = ObjectMotion.sine([0, 0, 2], 0.005, 0.25)  # axis normalised
    t = np.array([0.0, 1.0, 2.0, 3.0, 0.5, 1e9 + 1.0])
    expected = 0.005 * np.sin(2 * np.pi * 0.25 * t)
    np.testing.assert_allclose(m.offset(t)[:, 2], expected, atol=1e-9)
    np.testing.assert_allclose(m.offset(t)[:, :2], 0.0)
    assert m.offset(1.0).shape == (3,)
    assert m.period == 4.0
    assert m.peak_speed == pytest.approx(2 * np.pi * 0.25 * 0.005)


def test_linear_motion_goes_and_comes_back() -> None:
    v = np.array([0.02, -0.01, 0.0])
    m = ObjectMotion.linear(v, 2.0)
    np.testing.assert_allclose(m.offset(0.0), 0.0)
    np.testing.assert_allclose(m.offset(1.0), v * 1.0)
    np.testing.assert_allclose(m.offset(2.0), v * 2.0)
    np.testing.assert_allclose(m.offset(3.0), v * 1.0)
    np.testing.assert_allclose(m.offset(4.0), 0.0, atol=1e-15)
    np.testing.assert_allclose(m.offset(5.5), v * 1.5)  # second period
    np.testing.assert_allclose(m.velocity([0.5, 2.5]), [v, -v])


@pytest.mark.parametrize(
    "motion",
    [ObjectMotion.sine([1, 1, 0], 0.01, 0.7), ObjectMotion.linear([0.0, 0.03, 0.01], 0.8)],
)
def test_velocity_is_the_derivative_of_the_offset(motion: ObjectMotion) -> None:
    t = np.linspace(0.013, 5.0, 97)
    t = t[np.abs(np.mod(t, motion.period) - motion.duration) > 1e-3]  # not on a turnaround
    h = 1e-6
    fd = (motion.offset(t + h) - motion.offset(t - h)) / (2 * h)
    np.testing.assert_allclose(motion.velocity(t), fd, atol=1e-6)


def test_pose_translates_only() -> None:
    T = np.eye(4)
    T[:3, :3] = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    T[:3, 3] = [1, 2, 3]
    m = ObjectMotion.sine([0, 0, 1], 0.005, 0.25)
    P = m.pose(T, 1.0)
    np.testing.assert_allclose(P[:3, :3], T[:3, :3])
    np.testing.assert_allclose(P[:3, 3], [1, 2, 3.005])
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])  # input untouched


def test_turn_rotates_points_about_the_origin_by_the_closed_form_angle() -> None:
    m = ObjectMotion.sine([0, 0, 1], 0.004, 0.25).with_turn([0, 0, 3], np.radians(10), 0.2)
    c = np.array([1.0, 2.0, 3.0])
    P = np.array([[1.1, 2.0, 3.0], [1.0, 2.05, 3.2]])
    for t in (0.7, 1e9 + 0.7):  # UNIX times keep the phase
        a = np.radians(10) * np.sin(2 * np.pi * 0.2 * 0.7)
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        expected = (P - c) @ Rz.T + c + [0, 0, 0.004 * np.sin(2 * np.pi * 0.25 * 0.7)]
        np.testing.assert_allclose(m.move_points(P, c, t), expected, atol=1e-7)
    T = np.eye(4)
    T[:3, 3] = c
    np.testing.assert_allclose(m.pose(T, 0.7)[:3, :3], Rz, atol=1e-7)
    assert m.to_dict()["turn"] == {"axis": [0.0, 0.0, 1.0], "amplitude_deg": pytest.approx(10),
                                   "frequency": 0.2}  # fmt: skip
    np.testing.assert_allclose(ObjectMotion.sine([0, 0, 1], 0.004, 0.25).rotation(0.7), np.eye(3))


def test_a_turning_object_is_raycast_where_its_motion_puts_it() -> None:
    """A long bar turned and moved: rays hit it where the bar is then (numpy slab test)."""
    from drivers.camera.moving import MovingScene
    from planner.model.scene import SceneItem

    T = np.eye(4)
    m = ObjectMotion.sine([1, 0, 0], 0.003, 0.5).with_turn([0, 0, 1], np.radians(30), 0.25)
    box = SceneItem("b", "box", T, extents=np.array([0.3, 0.02, 0.02]), motion=m)
    scene = MovingScene([box])
    t = 0.8
    R, d = m.rotation(t), m.offset(t)
    rng = np.random.default_rng(1)
    ends = rng.uniform(-0.15, 0.15, (200, 3)) * [1, 0.3, 0.1]
    O = ends + np.array([0, 0, 1.0])
    V = np.tile([0.0, 0.0, -1.0], (len(O), 1))
    hits = scene.cast(O, V, t)
    # numpy: the ray in the box's frame at t, slab test
    o_b, v_b = (O - d) @ R, V @ R
    half = np.array([0.15, 0.01, 0.01])
    with np.errstate(divide="ignore"):
        t1, t2 = (-half - o_b) / v_b, (half - o_b) / v_b
    t_near = np.minimum(t1, t2).max(axis=1)
    t_far = np.maximum(t1, t2).min(axis=1)
    expected = np.where(t_near <= t_far, t_near, np.inf)
    hit = np.isfinite(expected)
    assert 10 < hit.sum() < len(O) - 10
    np.testing.assert_array_equal(np.isfinite(hits.t), hit)
    np.testing.assert_allclose(hits.t[hit], expected[hit], atol=1e-5)
    np.testing.assert_allclose(hits.normal[hit][:, 2], 1.0, atol=1e-5)  # the turn is about z
    assert np.abs(hits.normal[hit][:, :2]).max() < 1e-5


def test_the_turn_schema_names_its_unit_mistakes() -> None:
    from planner.model.motion import motion_from_schema
    from schemas.common import FieldError
    from schemas.motion import Motion

    ok = Motion.model_validate({"kind": "sine", "axis": [0, 0, 1], "amplitude": 0.005,
                                "frequency": 0.25,
                                "turn": {"axis": [0, 0, 1], "amplitude_deg": 8, "frequency": 0.1}})  # fmt: skip
    m = motion_from_schema(ok)
    assert m.turns and m.turn_amplitude == pytest.approx(np.radians(8))
    with pytest.raises((FieldError, ValueError), match="amplitude_deg"):
        Motion.model_validate({"kind": "linear", "velocity": [0.01, 0, 0], "duration": 1,
                               "turn": {"axis": [0, 0, 1], "amplitude_deg": 120, "frequency": 0.1}})  # fmt: skip
