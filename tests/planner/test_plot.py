"""Pictures: arm joint chains against the UR5e DH lengths (conventions section 2); the profile figure is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from planner.model.kinematics import RobotKinematics
from planner.plan.pipeline import run_scenario
from planner.plot import arm_points, plot_profiles, profiles_path
from planner.verify.numpy_beam import ur5e_dh_fk
from tests.planner.plan.test_pipeline import write_scenario

DH_LENGTHS = [0.1625, 0.425, 0.3922, 0.1333, 0.0997, 0.0996]  # conventions section 2: d and a


def test_joint_chain_lengths_and_flange() -> None:
    kin = RobotKinematics.ur5e()
    for q in np.random.default_rng(5).uniform(-np.pi, np.pi, (5, 6)):
        P = kin.joint_origins(q)
        links = np.linalg.norm(np.diff(P, axis=0), axis=1)
        np.testing.assert_allclose(links[links > 1e-9], DH_LENGTHS, atol=1e-9)
        np.testing.assert_allclose(P[-1], ur5e_dh_fk(q)[:3, 3], atol=1e-12)


def test_arm_points_in_world() -> None:
    from tests.planner.ik import ik_systems as sy

    system = sy.n2()
    pts = arm_points(system, system.home)
    for r, P in zip(system.robots, pts, strict=True):
        np.testing.assert_allclose(P[0], r.world_T_base[:3, 3], atol=1e-15)
        flange = r.world_T_base @ ur5e_dh_fk(system.split_q(system.home)[r.name])
        np.testing.assert_allclose(P[-1], flange[:3, 3], atol=1e-12)


def test_profiles_written_next_to_the_plot(tmp_path: Path) -> None:
    assert profiles_path("out/plan.png") == Path("out/plan_profiles.png")
    assert profiles_path("plan.svg") == Path("plan_profiles.svg")
    out = run_scenario(write_scenario(tmp_path), progress=False)
    png = tmp_path / "p.png"
    plot_profiles(out.system, out.targets, out.doc, png)
    assert png.stat().st_size > 30_000


def test_arrival_spots_are_the_targets(tmp_path: Path) -> None:
    from planner.plan.timed import spot_rays
    from planner.plot import _arrival_spots
    from planner.verify.spot import arrival_mask

    out = run_scenario(write_scenario(tmp_path), progress=False)
    traj = out.doc["trajectory"]
    t = np.asarray(traj["t"])
    idx = np.flatnonzero(arrival_mask(t, traj["segments"]))
    assert len(idx) == 18
    Q = np.asarray(traj["q"]["arm0"])[idx]
    p, v = spot_rays(out.system, Q)
    spots = _arrival_spots(out.system, out.doc, out.targets, Q, p, v)
    # each arrival's spot is on one target, and every target is reached once
    d = np.linalg.norm(spots[:, None, :] - out.targets.points[None], axis=2)
    assert d.min(axis=1).max() < 1e-9
    assert sorted(d.argmin(axis=1).tolist()) == list(range(18))


def test_profiles_with_the_fluence_panel(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from unittest import mock

    import matplotlib.figure

    from tests.paths import SCENARIOS

    out = run_scenario(SCENARIOS / "s_curve.yaml", progress=False)
    png = tmp_path / "s.png"
    titles: list[str] = []
    real = matplotlib.figure.Figure.savefig

    def grab(fig: matplotlib.figure.Figure, *a: object, **k: object) -> None:
        titles.extend(ax.get_title() for ax in fig.axes)
        real(fig, *a, **k)

    with mock.patch.object(matplotlib.figure.Figure, "savefig", grab):
        plot_profiles(out.system, out.targets, out.doc, png)
    assert png.stat().st_size > 30_000
    # 5 mW at 20 mm/s: 0.25 J/m, uniform within the 2 % speed band
    fluence = next(t for t in titles if t.startswith("fluence"))
    lo, hi = (float(x) for x in fluence.split()[1:4:2])
    assert 0.245 < lo <= hi < 0.255
