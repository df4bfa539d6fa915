"""The per-frame follower: continuity, limits, the laser gate and every stop."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from planner.beam.trace import trace_beam
from planner.data import shipped_scenario
from planner.ik import BeamIK
from planner.io.scenario import load_scenario, system_from_scenario
from planner.plan.scenario_planner import ik_options
from planner.safety.model import Safety
from planner.track.follow import TargetFollower, TrackSettings

P0 = np.array([-0.492, -0.55, -0.06])
N = np.array([0.0, 0.0, 1.0])
R_SMALL = 1e-12 * np.eye(3)  # m^2: a nearly exact tracker
DT, FRAME = 1 / 500, 1 / 30


@pytest.fixture(scope="module")
def ik() -> BeamIK:
    scn = load_scenario(shipped_scenario("breathing.yaml"))
    system = system_from_scenario(scn)
    return BeamIK(system, ik_options(scn.model.solver), Safety.from_scenario(scn, system))


def follower(ik: BeamIK, **kw: Any) -> TargetFollower:
    q0 = ik.solve(P0, N).q
    assert q0 is not None
    return TargetFollower(ik, q0, P0, None, TrackSettings(**kw))


def drive(f: TargetFollower, path: Any, seconds: float, frames_until: float = np.inf,
          R: np.ndarray = R_SMALL) -> list[tuple[float, Any]]:  # fmt: skip
    """Frames of ``path(t)`` at 30 Hz (received at capture), setpoints at 500 Hz."""
    out, next_frame = [], 0.0
    for k in range(round(seconds / DT)):
        now = k * DT
        if now + 1e-12 >= next_frame and now < frames_until:
            f.on_frame(now, path(now), N, now, R)
            next_frame += FRAME
        out.append((now, f.setpoint(now)))
    return out


def test_static_target_is_held_with_the_laser_on_once_its_velocity_is_known(ik: BeamIK) -> None:
    """After the first frame the target's velocity is unknown (50 mm/s RMS: 1.8 mm in the
    37 ms ahead), so the laser waits; from the second frame on it is held, laser on."""
    f = follower(ik)
    run = [(now, sp) for now, sp in drive(f, lambda t: P0, 1.0) if sp is not None]
    q = np.array([sp[1] for _, sp in run])
    np.testing.assert_allclose(q, np.broadcast_to(f.q0, q.shape), atol=1e-7)
    assert not run[0][1][3]
    assert all(sp[3] for now, sp in run if now >= FRAME)
    assert f.stopped is None


def test_moving_target_is_followed_and_each_setpoint_aims_at_its_time(ik: BeamIK) -> None:
    """A noise-free target at 20 mm/s: the setpoint sent at ``now`` for time t = now + lead
    puts the spot on the target at t (beam traced independently of the follower)."""
    v = np.array([0.02, 0.0, 0.0])
    f = follower(ik)
    run = drive(f, lambda t: P0 + v * t, 2.0)
    errors = [trace_beam(ik.system, sp[1], P0 + v * sp[0], N).error
              for now, sp in run if sp is not None and now > 0.5]  # fmt: skip
    assert max(errors) < 2e-5  # m: the limiter's and the line's residue
    assert all(sp[3] for now, sp in run if sp is not None and now > 0.5)


def test_setpoints_stay_within_limits_through_a_jump_and_the_laser_waits(ik: BeamIK) -> None:
    """The target jumps 20 mm: consecutive setpoints never exceed the velocity and
    acceleration limits, the laser is off while the arm catches up, then on again."""
    f = follower(ik)
    run = drive(f, lambda t: P0 + (np.array([0.02, 0, 0]) if t >= 0.5 else 0.0), 3.0)
    t = np.array([sp[0] for _, sp in run if sp is not None])
    q = np.array([sp[1] for _, sp in run if sp is not None])
    on = np.array([sp[3] for _, sp in run if sp is not None])
    lim = ik.system.limits
    vel = np.diff(q, axis=0) / np.diff(t)[:, None]
    acc = np.diff(vel, axis=0) / np.diff(t)[1:, None]
    assert np.all(np.abs(vel) <= lim.velocity * (1 + 1e-9))
    assert np.all(np.abs(acc) <= lim.acceleration * (1 + 1e-6))
    sent = np.array([now for now, sp in run if sp is not None])
    assert not on[sent >= 0.5][:5].any()  # off from the frame that saw the jump
    assert on[-1]  # back on once caught up
    err = trace_beam(ik.system, q[-1], P0 + np.array([0.02, 0, 0]), N).error
    assert err < 1e-5


def test_stale_stream_stops_after_three_frame_periods(ik: BeamIK) -> None:
    f = follower(ik)
    run = drive(f, lambda t: P0, 1.0, frames_until=0.5)
    last_frame = max(k * FRAME for k in range(16) if k * FRAME < 0.5)
    live = [now for now, sp in run if sp is not None]
    assert max(live) == pytest.approx(last_frame + 3 * FRAME, abs=DT)
    assert all(sp is None for now, sp in run if now > last_frame + 3 * FRAME + DT)
    assert f.stopped is not None and "stale" in f.stopped
    f.on_frame(1.0, P0, N, 1.0, R_SMALL)  # a late frame does not restart it
    assert f.setpoint(1.0) is None


def test_staleness_stops_exactly_at_its_limit(ik: BeamIK) -> None:
    f = follower(ik)
    f.on_frame(0.0, P0, N, 0.0, R_SMALL)  # received at 0 s
    limit = f.settings.stale_after
    assert limit == 3 * FRAME  # three frame periods of a 30 Hz stream
    assert f.setpoint(limit - 1e-9) is not None and f.check_stale(limit) is None
    assert f.setpoint(limit + 1e-9) is None
    assert f.stopped == "target stream stale: no frame for 100 ms (limit 100 ms)"


def test_target_leaving_the_region_stops(ik: BeamIK) -> None:
    f = follower(ik, max_excursion=0.05)
    drive(f, lambda t: P0 + (np.array([0.0, 0.06, 0]) if t >= 0.2 else 0.0), 0.5)
    assert f.stopped is not None and "from its first estimate" in f.stopped
    assert f.setpoint(0.6) is None


def test_target_entering_a_keep_out_volume_stops(ik: BeamIK) -> None:
    """Every solution passes the safety rules: a target predicted inside a keep-out sphere
    has none, and the follower stops with that reason."""
    from planner.model.transforms import make_T
    from planner.safety.shapes import sphere

    eye = sphere("eye", 0.01, make_T(p=P0 + np.array([0.03, 0.0, 0.0])))
    rules = Safety(ik.system, keep_out=[eye])
    guarded = BeamIK(ik.system, ik.options, rules)
    f = follower(guarded)
    drive(f, lambda t: P0 + (np.array([0.03, 0, 0]) if t >= 0.2 else 0.0), 0.4)
    assert f.stopped is not None and "keep_out" in f.stopped
    assert f.setpoint(0.5) is None


def test_a_discontinuous_solution_stops(ik: BeamIK) -> None:
    """A target the arm reaches only in another posture (far in joint space) is not swept
    to at full speed: the follower stops."""
    f = follower(ik, max_excursion=10.0)
    out = f.on_frame(0.0, np.array([-0.49, -0.13, 0.8]), N, 0.0, R_SMALL)  # above the mirror
    assert out.stopped is not None and "rad from the command" in out.stopped
    assert f.setpoint(0.0) is None


def test_noisy_prediction_keeps_the_laser_off_when_over_tolerance(ik: BeamIK) -> None:
    """With 2 mm measurement noise the prediction's uncertainty alone is over a 1 mm
    tolerance: the laser never goes on."""
    f = follower(ik)
    rng = np.random.default_rng(0)
    R = (2e-3) ** 2 * np.eye(3)
    run = drive(f, lambda t: P0 + 2e-3 * rng.standard_normal(3), 1.0, R=R)
    assert not any(sp[3] for _, sp in run if sp is not None)


def test_a_setpoint_that_would_sweep_the_beam_through_a_keep_out_is_not_sent(ik: BeamIK) -> None:
    """The frame solutions on both sides of a small keep-out sphere are safe, the setpoints
    between them would sweep the spot through it: the first unsafe setpoint is not sent, the
    follower stops as unsafe. Independent check: every setpoint that was sent, traced with
    the numpy beam, keeps the spot out of the sphere."""
    from planner.model.transforms import make_T
    from planner.safety.shapes import sphere

    centre = P0 + np.array([0.010, 0.0, 0.0])
    eye = sphere("eye", 0.003, make_T(p=centre))
    guarded = BeamIK(ik.system, ik.options, Safety(ik.system, keep_out=[eye]))
    f = follower(guarded)
    out = drive(f, lambda t: P0 + (np.array([0.02, 0, 0]) if t >= 0.2 else 0.0), 0.6)
    sent = [sp for _, sp in out if sp is not None]
    assert f.unsafe and f.stopped is not None and "not sent: keep_out" in f.stopped, f.stopped
    assert f.checked >= len(sent) > 50
    for _, q, _, _ in sent:
        spot = trace_beam(ik.system, q, P0, N).spot
        assert np.linalg.norm(spot - centre) > 0.003
    assert f.setpoint(0.7) is None


def test_the_spot_speed_is_capped(ik: BeamIK) -> None:
    """A 30 mm step of the target: the setpoints move the spot at most ``max_spot_speed``
    (measured with the numpy beam on the target plane, independent of the limiter's
    Jacobian)."""
    f = follower(ik, max_spot_speed=0.05)
    out = drive(f, lambda t: P0 + (np.array([0.03, 0, 0]) if t >= 0.1 else 0.0), 1.2)
    spots = np.array([trace_beam(ik.system, sp[1], P0, N).spot for _, sp in out if sp is not None])
    speed = np.linalg.norm(np.diff(spots, axis=0), axis=1) / DT
    print(
        f"spot speed max {speed.max():.4f} m/s; final {1e3 * np.linalg.norm(spots[-1] - P0 - [0.03, 0, 0]):.2f} mm off"
    )
    assert speed.max() <= 0.05 * 1.05
    assert np.linalg.norm(spots[-1] - (P0 + np.array([0.03, 0, 0]))) < 1e-3  # it still gets there


def _eye_beside(ik: BeamIK, attached: bool) -> tuple[TargetFollower, Any, np.ndarray]:
    from planner.model.transforms import make_T
    from planner.safety.shapes import sphere

    offset = np.array([0.0, 0.006, 0.0])  # the eye 6 mm beside the target, radius 3 mm
    eye = sphere("eye", 0.003, make_T(p=P0 + offset))
    guarded = BeamIK(ik.system, ik.options, Safety(ik.system, keep_out=[eye]))
    q0 = guarded.solve(P0, N).q
    assert q0 is not None
    poses = {"eye": make_T(p=P0 + offset)} if attached else {}
    return TargetFollower(guarded, q0, P0, None, TrackSettings(), attached=poses), guarded, offset


def test_an_attached_keep_out_moves_with_the_face(ik: BeamIK) -> None:
    """The face (target and eye) moves 12 mm across, through where the eye was: attached,
    the eye moves along and the spot follows the target; every sent setpoint, traced with
    the numpy beam, stays out of the eye where the face put it (an independent check)."""
    f, guarded, offset = _eye_beside(ik, attached=True)
    move = np.array([0.0, 0.012, 0.0])
    out = drive(f, lambda t: P0 + move * min(t / 0.4, 1.0), 1.0)
    assert f.stopped is None, f.stopped
    np.testing.assert_allclose(f.keep_out_shift, move, atol=1e-3)
    for now, sp in out:
        if sp is None:
            continue
        eye_now = P0 + offset + move * min(now / 0.4, 1.0)
        tr = trace_beam(ik.system, sp[1], P0 + move * min(now / 0.4, 1.0), N)
        a, b = tr.hits[-1], tr.spot  # the last segment: mirror to spot
        s = np.clip((eye_now - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
        assert np.linalg.norm(a + s * (b - a) - eye_now) > 0.003
    f.release()  # the shared rules are the scenario's again
    assert guarded.safety is not None and guarded.safety.target(P0 + offset) is not None


def test_an_unattached_keep_out_stays_where_the_scenario_put_it(ik: BeamIK) -> None:
    f, _, _ = _eye_beside(ik, attached=False)
    move = np.array([0.0, 0.012, 0.0])
    drive(f, lambda t: P0 + move * min(t / 0.4, 1.0), 1.0)
    assert f.stopped is not None and "keep_out" in f.stopped  # the target ran into the eye


def test_an_attached_keep_out_turns_with_a_turning_face(ik: BeamIK) -> None:
    """The face turns 15 deg about a vertical axis 30 mm behind the target: with the face's
    markers the eye is placed where the turn puts it (within 0.05 mm of the closed form,
    numpy rotation), not merely shifted with the target (4 mm off, the old behaviour); every
    sent setpoint's beam (numpy trace) stays out of the eye where the face put it then."""
    from planner.model.transforms import make_T
    from planner.safety.shapes import sphere

    pivot = P0 + np.array([0.0, -0.03, 0.0])
    eye_rest = P0 + np.array([0.015, 0.006, 0.0])
    markers = P0 + np.array([[0, 0, 0], [0.02, 0, 0], [-0.02, 0, 0], [0, 0.02, 0], [0, -0.02, 0]])
    guarded = BeamIK(
        ik.system,
        ik.options,
        Safety(ik.system, keep_out=[sphere("eye", 0.003, make_T(p=eye_rest))]),
    )
    q0 = guarded.solve(P0, N).q
    assert q0 is not None
    f = TargetFollower(guarded, q0, P0, None, TrackSettings(), attached={"eye": make_T(p=eye_rest)},
                       markers=markers)  # fmt: skip

    def turned(x: np.ndarray, t: float) -> np.ndarray:
        a = np.radians(15) * min(t / 0.5, 1.0)
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        return (x - pivot) @ Rz.T + pivot

    next_frame, sent = 0.0, []
    for k in range(round(1.0 / DT)):
        now = k * DT
        if now + 1e-12 >= next_frame:
            f.on_frame(now, turned(P0, now), N, now, R_SMALL, markers=turned(markers, now))
            next_frame += FRAME
        sp = f.setpoint(now)
        if sp is not None:
            sent.append(sp)
    assert f.stopped is None, f.stopped
    placed = f.object_T_rest[:3, :3] @ eye_rest + f.object_T_rest[:3, 3]
    truth = turned(eye_rest, 1.0)
    assert np.linalg.norm(placed - truth) < 5e-5
    shifted = eye_rest + turned(P0, 1.0) - P0  # translation only
    assert np.linalg.norm(shifted - truth) > 3.5e-3
    assert guarded.safety is not None and guarded.safety.target(truth) is not None
    for t, q, _, _ in sent:
        tr = trace_beam(ik.system, q, turned(P0, t), N)
        a, b = tr.hits[-1], tr.spot
        s = np.clip((turned(eye_rest, t) - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
        assert np.linalg.norm(a + s * (b - a) - turned(eye_rest, t)) > 0.003
    f.release()
    assert guarded.safety.target(eye_rest) is not None


def test_the_sweep_between_two_safe_setpoints_is_checked(ik: BeamIK) -> None:
    """Setpoints aiming 4 mm apart on the board, each beam 2 mm clear of a 0.8 mm keep-out
    sphere that the beam to the midpoint crosses: each end is safe, the sweep between them
    is not, and it is found."""
    from planner.model.transforms import make_T
    from planner.safety.shapes import sphere

    pa, pb = P0, P0 + np.array([0.004, 0.0, 0.0])
    mid = (pa + pb) / 2
    q_mid = ik.solve(mid, N).q
    assert q_mid is not None
    back = trace_beam(ik.system, q_mid, mid, N).hits[-1] - mid  # towards the mirror
    centre = mid + 0.002 * back / np.linalg.norm(back)
    guarded = BeamIK(
        ik.system, ik.options, Safety(ik.system, keep_out=[sphere("eye", 8e-4, make_T(p=centre))])
    )
    qa, qb = guarded.solve(pa, N).q, guarded.solve(pb, N).q
    assert qa is not None and qb is not None  # both ends are safe on their own
    f = TargetFollower(guarded, qa, pa, None, TrackSettings())
    f.on_frame(0.0, pa, N, 0.0, R_SMALL)
    n = f.sweep_steps(qa, qb)
    assert n >= max(np.abs(qb - qa).max() / 1e-3, 20)  # 4 mm of spot in 0.2 mm steps
    f.q = qb.copy()
    assert f._violation(qb) is None  # the end alone (no sweep) is safe
    f.q = qa.copy()
    bad = f._violation(qb)
    assert bad is not None and "keep_out" in bad and "on the sweep" in bad, bad


def test_capped_setpoints_at_uneven_intervals_stay_within_the_acceleration_limit(
    ik: BeamIK,
) -> None:
    """A loaded sender's setpoints come 2.8 ms then 1.2 ms apart while the spot-speed cap
    holds a 30 mm step back: every velocity change between consecutive setpoints is within
    the acceleration limit over their own interval (as the driver checks it)."""
    f = follower(ik, max_spot_speed=0.05)
    sent, now, k, next_frame = [], 0.0, 0, 0.0
    while now < 0.6:
        if now + 1e-12 >= next_frame:
            f.on_frame(now, P0 + (np.array([0.03, 0, 0]) if now >= 0.1 else 0.0), N, now, R_SMALL)
            next_frame += FRAME
        if (sp := f.setpoint(now)) is not None:
            sent.append(sp)
        now += 2.8e-3 if k % 2 else 1.2e-3
        k += 1
    t = np.array([sp[0] for sp in sent])
    qd = np.array([sp[2] for sp in sent])
    a_max = ik.system.limits.acceleration
    rate = np.abs(np.diff(qd, axis=0)) / np.diff(t)[:, None]
    assert (rate <= a_max * (1 + 1e-6)).all(), (rate / a_max).max()


@pytest.mark.parametrize("fault", ["missing", "moved"])
def test_markers_that_cannot_place_the_attached_volumes_stop_tracking(
    ik: BeamIK, fault: str
) -> None:
    """An occluded marker (the frame has one fewer) or a marker 20 mm off its rigid place
    (a swapped match): the volumes' place is unknown, so the follower stops instead of
    moving the eye on by extrapolation or by a wrong fit."""
    from planner.model.transforms import make_T
    from planner.track.follow import MAX_MARKER_RESIDUAL

    eye_rest = P0 + np.array([0.015, 0.006, 0.0])
    markers = P0 + np.array([[0, 0, 0], [0.02, 0, 0], [-0.02, 0, 0], [0, 0.02, 0], [0, -0.02, 0]])
    q0 = ik.solve(P0, N).q
    assert q0 is not None
    f = TargetFollower(ik, q0, P0, None, TrackSettings(), attached={"eye": make_T(p=eye_rest)},
                       markers=markers)  # fmt: skip
    f.on_frame(0.0, P0, N, 0.0, R_SMALL, markers=markers)
    assert f.stopped is None
    bad = (
        markers[:-1] if fault == "missing" else markers + np.array([[0.02, 0, 0]] + [[0, 0, 0]] * 4)
    )
    if fault == "moved":  # independent: the residual of the best rigid fit exceeds the limit
        from planner.calibration.handeye import fit_rigid

        T = fit_rigid(markers, bad)
        rms = np.sqrt(np.mean(np.sum((bad - (markers @ T[:3, :3].T + T[:3, 3])) ** 2, axis=1)))
        assert rms > MAX_MARKER_RESIDUAL
    out = f.on_frame(FRAME, P0, N, FRAME, R_SMALL, markers=bad)
    assert f.stopped is not None and out.stopped == f.stopped
    assert ("missing" if fault == "missing" else "do not move rigidly") in f.stopped
