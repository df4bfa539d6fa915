"""The spot servo against the simulated camera in-process (no subprocesses, no bus).

The world: ``paper_n1`` as the planner's model; its truth has the laser tilted 0.4 deg and the
mirror mount 3 mm further out, so open-loop spots land ~5 mm off; the camera is the driver's
SimCamera on the truth with the D435 noise model; measurements go through the model's camera
pose. The independent check of "converged" is the truth's *noiseless* spot at the final
joints, not the servo's own measurement.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from planner.beam.trace import trace_beam
from planner.bench.servo_world import UP, SimWorld, board_targets
from planner.ik import BeamIK
from planner.model.status import Reason
from planner.servo import (
    Corrector,
    ServoSettings,
    ServoStatus,
    SpotFrame,
    SpotMeasurement,
    SpotModel,
    average_frames,
    servo,
)


@pytest.fixture(scope="module")
def world() -> SimWorld:
    return SimWorld(seed=7)


@pytest.fixture(scope="module")
def plans(world: SimWorld) -> list[tuple[np.ndarray, np.ndarray]]:
    """(target, open-loop q) for six board targets, solved in the model."""
    ik = BeamIK(world.model)
    out = []
    for p in board_targets(6, seed=11):
        sol = ik.solve(p, UP)
        assert sol.ok and sol.q is not None
        out.append((p, sol.q))
    return out


def test_spot_jacobian_matches_central_differences_of_the_numpy_trace(world: SimWorld) -> None:
    model = SpotModel(world.model)
    rng = np.random.default_rng(3)
    for p, n in [
        (board_targets(1, 5)[0], UP),
        (np.array([-0.5, -0.5, 0.02]), np.array([0.3, 0.1, 1.0])),
    ]:
        n = n / np.linalg.norm(n)
        q = BeamIK(world.model).solve(p, n).q
        assert q is not None
        q = q + rng.normal(0, 0.01, q.shape)
        sj = model.evaluate(q, p, n)
        h = 1e-6
        fd = np.column_stack([
            (trace_beam(world.model, q + h * e, p, n).spot - trace_beam(world.model, q - h * e, p, n).spot) / (2 * h)
            for e in np.eye(len(q))
        ])  # fmt: skip
        np.testing.assert_allclose(sj.jacobian, fd, atol=1e-7)
        np.testing.assert_allclose(sj.spot, trace_beam(world.model, q, p, n).spot, atol=1e-12)
        # the spot stays on the plane: the Jacobian has no normal component
        np.testing.assert_allclose(n @ sj.jacobian, 0.0, atol=1e-9)
        np.testing.assert_allclose(sj.axes.T @ n, 0.0, atol=1e-12)


def _true_error(world: SimWorld, q: np.ndarray, p: np.ndarray) -> float:
    spot = world.true_spot(q)
    assert spot is not None
    return float(np.linalg.norm(spot - p))


@pytest.mark.parametrize("with_normal", [True, False])
def test_servo_converges_from_5mm_to_half_a_millimetre_within_25_frames(
    world: SimWorld, plans: list[Any], with_normal: bool
) -> None:
    corrector = Corrector(world.model)
    for p, q0 in plans:
        open_loop = _true_error(world, q0, p)
        assert 3e-3 < open_loop < 8e-3  # the perturbed truth: a few millimetres open loop
        r = servo(world.measure, q0, p, UP if with_normal else None, corrector)
        assert r.status is ServoStatus.CONVERGED, r
        assert abs(r.error_before - open_loop) < 1e-3  # the first measurement sees it (noise)
        assert r.error_after <= 0.3e-3 and r.error_after == r.errors[-1]
        assert _true_error(world, r.q, p) <= 0.5e-3
        # 1 frame open loop, 3 per step, 9 per confirmation of a measurement within the
        # tolerance but not with confidence (one per joints at most)
        confirms = len(r.errors) - 1 - r.iterations
        s = corrector.settings
        assert 0 <= confirms <= r.iterations and r.iterations >= 1
        assert r.frames == 1 + s.frames * r.iterations + s.confirm_frames * confirms <= 25
        assert np.max(np.abs(r.q - q0)) <= corrector.settings.max_step + 1e-12


def test_not_seen_at_the_start_commands_nothing(world: SimWorld, plans: list[Any]) -> None:
    p, q0 = plans[0]
    calls: list[np.ndarray] = []

    def blind(q: np.ndarray, frames: int) -> SpotMeasurement | None:
        calls.append(q)
        return average_frames([SpotFrame(None)] * frames, world.world_T_camera)

    r = servo(blind, q0, p, UP, Corrector(world.model))
    assert r.status is ServoStatus.NOT_SEEN and r.iterations == 0 and r.frames == 1
    assert np.isnan(r.error_before) and np.isnan(r.error_after) and r.spot is None
    assert len(calls) == 1 and np.array_equal(r.q, q0)


def test_spot_lost_after_a_step_goes_back_to_the_best_configuration(
    world: SimWorld, plans: list[Any]
) -> None:
    p, q0 = plans[1]
    calls: list[np.ndarray] = []

    def lost_after_move(q: np.ndarray, frames: int) -> SpotMeasurement | None:
        calls.append(np.array(q))
        return world.measure(q, frames) if np.array_equal(q, q0) else None

    r = servo(lost_after_move, q0, p, UP, Corrector(world.model))
    assert r.status is ServoStatus.NOT_SEEN and r.iterations == 1
    assert len(calls) == 3 and np.array_equal(calls[-1], q0) and np.array_equal(r.q, q0)
    assert r.error_after == pytest.approx(r.errors[-1]) and 3e-3 < r.error_after < 8e-3


def test_a_step_beyond_a_joint_limit_is_refused_with_the_joint_named(
    world: SimWorld, plans: list[Any]
) -> None:
    p, q0 = plans[2]
    r0 = world.model.robots[0]
    tight = replace(r0.limits, lower=q0 - 1e-4, upper=q0 + 1e-4)
    system = replace(world.model, robots=(replace(r0, limits=tight),))
    r = servo(world.measure, q0, p, UP, Corrector(system))
    assert r.status is ServoStatus.REFUSED and r.iterations == 0
    assert r.failure is not None and r.failure.reason is Reason.JOINT_LIMITS
    assert "arm0" in r.failure.detail and "rad beyond its" in r.failure.detail
    assert np.array_equal(r.q, q0) and r.error_after == r.error_before > 3e-3


def test_a_measurement_that_does_not_follow_the_arm_stops_as_not_improving(
    world: SimWorld, plans: list[Any]
) -> None:
    p, q0 = plans[3]
    stuck = p + np.array([4e-3, 0.0, 0.0])
    calls: list[np.ndarray] = []

    def frozen(q: np.ndarray, frames: int) -> SpotMeasurement:
        calls.append(np.array(q))
        return SpotMeasurement(stuck, frames, frames, 1.0, 0.0)

    r = servo(frozen, q0, p, UP, Corrector(world.model))
    assert r.status is ServoStatus.NOT_IMPROVING and r.iterations == 1
    assert np.array_equal(calls[-1], q0) and np.array_equal(r.q, q0)  # went back
    assert r.errors == pytest.approx((4e-3, 4e-3, 4e-3)) and r.frames == 1 + 3 + 3


def test_a_stop_aborts_before_the_next_move(world: SimWorld, plans: list[Any]) -> None:
    p, q0 = plans[4]
    calls: list[np.ndarray] = []

    def measure(q: np.ndarray, frames: int) -> SpotMeasurement | None:
        calls.append(np.array(q))
        return world.measure(q, frames)

    r = servo(measure, q0, p, UP, Corrector(world.model), should_stop=lambda: len(calls) >= 1)
    assert r.status is ServoStatus.ABORTED and len(calls) == 1 and np.array_equal(r.q, q0)
    r = servo(measure, q0, p, UP, Corrector(world.model), should_stop=lambda: True)
    assert r.status is ServoStatus.ABORTED and len(calls) == 1 and r.frames == 0


def test_max_iterations_zero_measures_once(world: SimWorld, plans: list[Any]) -> None:
    p, q0 = plans[5]
    r = servo(world.measure, q0, p, UP, Corrector(world.model), ServoSettings(max_iterations=0))
    assert r.status is ServoStatus.MAX_ITERATIONS and r.frames == 1 and r.iterations == 0
    assert r.to_json()["measured_error_after"] == pytest.approx(r.error_before)


@pytest.mark.parametrize(
    "kw",
    [{"tolerance": float("nan")}, {"tolerance": 0.0}, {"frames": 0}, {"max_step": -1.0},
     {"max_iterations": -1}, {"first_frames": 0}, {"min_improvement": 1.0}, {"damping": float("inf")}],
)  # fmt: skip
def test_bad_settings_are_refused_with_the_value(kw: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="servo"):
        ServoSettings(**kw)  # type: ignore[arg-type]


def test_a_plane_without_a_finite_normal_is_refused(world: SimWorld) -> None:
    with pytest.raises(ValueError, match="normal"):
        SpotModel(world.model).evaluate(world.model.home, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="normal"):
        SpotModel(world.model).evaluate(world.model.home, np.zeros(3), np.array([np.nan, 0, 1]))


def test_near_the_noise_floor_the_loop_keeps_correcting_until_its_iteration_limit(
    world: SimWorld, plans: list[Any]
) -> None:
    p, q0 = plans[3]
    noisy_floor = p + np.array([0.0, 0.5e-3, 0.0])  # within 2 x 0.3 mm, never better

    def floor(q: np.ndarray, frames: int) -> SpotMeasurement:
        return SpotMeasurement(noisy_floor, frames, frames, 1.0, 0.0)

    r = servo(floor, q0, p, UP, Corrector(world.model), ServoSettings(max_iterations=3))
    assert r.status is ServoStatus.MAX_ITERATIONS and r.iterations == 3
    assert r.frames == 1 + 3 * 3 and not np.array_equal(r.q, q0)
    with pytest.raises(ValueError, match="noise_floor"):
        ServoSettings(noise_floor=0.5)


def test_a_correction_is_checked_at_the_measured_spot_plus_j_dq_not_the_model_spot(
    world: SimWorld, plans: list[Any]
) -> None:
    """A keep-out sphere on the beam the step will really produce (ending at the measured
    spot + J dq, which the truth confirms) but clear of the model's beam (its spot is off by
    the calibration error): the step is refused as keep_out."""
    from planner.model.transforms import make_T
    from planner.safety import sphere
    from planner.safety.model import Safety

    p, q0 = plans[0]
    measured = world.true_spot(q0)  # noiseless: what the camera sees, up to its noise
    assert measured is not None
    plain = Corrector(world.model)
    pn = plain.model.plane_normal(q0, p, UP)
    free = plain.step(q0, p, UP, pn, measured - p)
    assert free.ok
    expected = measured + plain.model.evaluate(q0, p, pn).jacobian @ free.dq
    real = world.true_spot(free.q)
    assert real is not None and np.linalg.norm(real - expected) < 0.3e-3  # linear: it is real
    tr = trace_beam(world.model, free.q, p, UP)
    hit, model_spot = tr.hits[-1], tr.spot
    assert np.linalg.norm(model_spot - expected) > 3e-3  # the model is a few mm off
    c = expected + 0.01 * (hit - expected) / np.linalg.norm(hit - expected)
    r = 0.002

    def dist(a: np.ndarray, b: np.ndarray) -> float:  # plain numpy point-segment distance
        s = np.clip((c - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        return float(np.linalg.norm(c - (a + s * (b - a))))

    assert dist(hit, expected) < r < dist(hit, model_spot)  # in the real beam, not the model's
    assert np.linalg.norm(c - p) > r  # the target itself is outside the volume
    guarded = Corrector(
        world.model, Safety(world.model, keep_out=(sphere("mole", r, make_T(p=c)),))
    )
    st = guarded.step(q0, p, UP, pn, measured - p)
    assert not st.ok and st.failure is not None and st.failure.reason is Reason.KEEP_OUT
    assert "keep_out/mole" in st.failure.detail and np.array_equal(st.q, q0)
