"""The node's online calibration: background refits, the includable file, the published
version, the swap between requests, the rest sampler, and bad input of every kind."""

from __future__ import annotations

import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.bus.session import Keys, encode, open_session
from planner.calibration.simulate import simulate_beam
from planner.data import shipped_scenario
from planner.errors import InputError
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.system import System
from planner.model.transforms import axis_angle_to_matrix, inv_T, make_T, transform_points
from planner.service.client import PlanClient, make_request
from planner.service.handler import handler_from_scenario
from planner.service.node import PlannerNode
from planner.service.online import OnlineCalibrator, RestSampler
from planner.service.online_file import check_output_file, is_online_file
from schemas.messages import CalibrationMessage, JointState, SpotMessage
from tests.drivers.conftest import free_port, wait_for
from tests.planner.raw_zenoh import Inbox, raw_session
from tests.planner.service.plans import as_plan

PREFIX = "onlinetest"
AIM = np.array([-0.492, -0.55, -0.06])  # on paper_n1's board


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("scn")
    return Path(shutil.copy(shipped_scenario("paper_n1.yaml"), folder / "paper_n1.yaml"))


@pytest.fixture(scope="module")
def nominal(scenario: Path) -> System:
    return system_from_scenario(load_scenario(scenario))


@pytest.fixture(scope="module")
def truth(nominal: System) -> System:
    """Laser tilted 0.4 deg, mirror mount 3 mm along its normal."""
    L = nominal.world_T_laser @ make_T(axis_angle_to_matrix(np.deg2rad([0.3, -0.26, 0.0])))
    M = nominal.robots[0].mirror.flange_T_mirror @ make_T(p=[0.0, 0.0, 0.003])
    return nominal.with_params(L, {"arm0": M})


def true_samples(truth: System, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Noise-free spots of the truth at ``n`` varied configurations, on 2 placements (the
    surfaces ``board0`` and ``board1``: they are not scene objects)."""
    data = simulate_beam(truth, "arm0", n // 2, 2, aim_world=AIM, rng=np.random.default_rng(seed))
    return data.q, data.spots_world, [f"board{b}" for b in data.boards]


def test_output_file_never_overwrites_a_users_file(tmp_path: Path, scenario: Path) -> None:
    mine = tmp_path / "calibration.yaml"
    mine.write_text("system: {}\nreport: {kind: beam}\n")
    with pytest.raises(InputError, match="refusing to overwrite"):
        check_output_file(mine, scenario)
    with pytest.raises(InputError, match="scenario itself"):
        check_output_file(scenario, scenario)
    with pytest.raises(InputError, match="directory"):
        check_output_file(tmp_path, scenario)
    fresh = check_output_file(tmp_path / "sub" / "online.yaml", scenario)
    assert fresh.is_absolute() and not fresh.exists()
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00")
    assert not is_online_file(tmp_path / "bin.yaml")


def calibrator(
    nominal: System, scenario: Path, out: Path, **kw: Any
) -> tuple[OnlineCalibrator, list]:
    got: list[Any] = []
    cal = OnlineCalibrator(
        nominal, out, rebuild=lambda f: handler_from_scenario(scenario, (f,)),
        publish=got.append, **kw,
    )  # fmt: skip
    return cal, got


def test_refits_write_an_includable_file_and_publish_versions(
    tmp_path: Path, scenario: Path, nominal: System, truth: System
) -> None:
    out = tmp_path / "online.yaml"
    cal, bodies = calibrator(nominal, scenario, out)
    installed: list[tuple[Any, Any]] = []
    cal.on_update = lambda h, c: installed.append((h, c))
    cal.start()
    try:
        q, spots, boards = true_samples(truth, 12)
        for qk, sk, b in zip(q, spots, boards, strict=True):
            assert cal.add_sample({"arm0": qk}, sk, surface=b)
        assert cal.wait_idle(120)
    finally:
        cal.close()
    msgs = [CalibrationMessage.model_validate_json(b) for b in bodies]
    versions = [m.version for m in msgs]
    assert versions and versions == list(range(1, len(versions) + 1))
    assert msgs[-1].version == cal.current.version and msgs[-1].samples == cal.current.samples
    assert [c.version for _, c in installed] == versions
    assert is_online_file(out) and check_output_file(out, scenario) == out.resolve()
    # a scenario including the file gets exactly the calibrated values ...
    user = scenario.parent / "with_online.yaml"
    user.write_text(scenario.read_text() + f"include: [{out}]\n")
    loaded = system_from_scenario(load_scenario(user))
    np.testing.assert_allclose(loaded.world_T_laser, cal.current.system.world_T_laser, atol=1e-12)
    M = cal.current.system.robots[0].mirror.flange_T_mirror
    np.testing.assert_allclose(loaded.robots[0].mirror.flange_T_mirror, M, atol=1e-12)
    assert msgs[-1].calibration["system"] == cal.current.document["system"]  # type: ignore[index]
    # ... which predict the true spots (noise-free samples: exact in the observable directions)
    model = BeamModel(loaded)
    assert max(model.trace(qk, sk).error for qk, sk in zip(q, spots, strict=True)) < 1e-8
    assert installed[-1][0].system.world_T_laser.tolist() == loaded.world_T_laser.tolist()


BAD_SAMPLES: list[tuple[Any, Any]] = [
    (None, None),
    ("x", [1, 2]),
    ([np.nan] * 6, [0.0, 0.0, 0.0]),
    ({"arm9": [0.0] * 6}, [0.0, 0.0, 0.0]),
    ({"arm0": [0.0] * 6}, [float("inf"), 0.0, 0.0]),
    ({"arm0": list(range(10**5))}, [0.0, 0.0, 0.0]),
    ({"arm0": [0.0] * 6}, [-492.0, -550.0, -60.0]),  # millimetres
    ({"arm0": [[0.0] * 6]}, {"x": 1}),
]


def test_garbage_never_crashes_the_refit_thread(
    tmp_path: Path, scenario: Path, nominal: System, truth: System
) -> None:
    out = tmp_path / "online.yaml"
    crashes = {"n": 0}

    def flaky(f: Path) -> Any:
        if crashes["n"] == 0:
            crashes["n"] += 1
            raise RuntimeError("rebuild bug")
        return handler_from_scenario(scenario, (f,))

    cal, bodies = calibrator(nominal, scenario, out)
    cal.rebuild = flaky
    cal.start()
    try:
        for q, s in BAD_SAMPLES:
            assert not cal.add_sample(q, s)
            assert not cal.add_camera_spot(q, s)
        assert cal.rejected + cal.implausible == 2 * len(BAD_SAMPLES) and cal.n_samples == 0
        q, spots, boards = true_samples(truth, 10, seed=1)
        for qk, sk, b in zip(q, spots, boards, strict=True):
            cal.add_sample(qk, sk, surface=b)
            assert cal.wait_idle(60)  # one refit per sample: the first accepted one crashes
        assert cal._thread.is_alive()
    finally:
        cal.close()
    assert crashes["n"] == 1 and cal.current.version >= 1 and bodies


class FakeJoints:
    def __init__(self) -> None:
        self.entry: tuple[float, np.ndarray, np.ndarray] | None = None

    def set(self, q: Any, qd: Any, age: float = 0.0) -> None:
        self.entry = (time.monotonic() - age, np.asarray(q, float), np.asarray(qd, float))

    def __call__(self, robot: str) -> tuple[float, np.ndarray, np.ndarray] | None:
        return self.entry


def test_rest_sampler_takes_one_sample_per_rest_configuration(nominal: System) -> None:
    taken: list[tuple[Any, Any]] = []
    cal = OnlineCalibrator(nominal, Path("unused.yaml"))
    cal.add_camera_spot = lambda q, p, **_: taken.append((q, p)) or True  # type: ignore[method-assign]
    joints = FakeJoints()
    sampler = RestSampler(cal, ("arm0",), joints)
    q0, p = nominal.home, [0.01, 0.02, 0.9]
    assert not sampler.on_spot(p, 1.0)  # no joint state yet
    joints.set(q0, [0.0, 0.3, 0, 0, 0, 0])
    assert not sampler.on_spot(p, 1.0) and not sampler.on_spot(p, 1.0)  # moving
    joints.set(q0, np.zeros(6))
    assert not sampler.on_spot(p, 1.0)  # first frame at rest
    assert sampler.on_spot(p, 1.0)  # second frame at the same joints: a sample
    assert not sampler.on_spot(p, 1.0)  # that configuration has its sample
    q1 = q0 + 0.01
    joints.set(q1, np.zeros(6))
    assert not sampler.on_spot(p, 0.1)  # a dim spot is no sample
    assert not sampler.on_spot(None, 1.0)  # no spot seen
    assert sampler.on_spot(p, 1.0)  # the joints were at q1 on the frame before as well
    joints.set(q1, np.zeros(6), age=1.0)
    assert not sampler.on_spot(p, 1.0)  # stale joint state
    joints.set(q1, np.zeros(6))
    assert not sampler.on_spot(p, 1.0) and not sampler.on_spot(p, 1.0)  # q1 has its sample
    assert len(taken) == 2 and np.allclose(taken[1][0], q1)
    joints.set(q1, [np.nan] * 6)
    assert not sampler.on_spot(p, 1.0)


@pytest.fixture
def bus(scenario: Path, nominal: System, tmp_path: Path) -> Iterator[tuple[str, PlannerNode]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(listen=True, endpoint=endpoint)
    online, _ = calibrator(nominal, scenario, tmp_path / "online.yaml")
    node = PlannerNode(handler_from_scenario(scenario), session, Keys(PREFIX), online=online)
    node.start()
    yield endpoint, node
    node.close()
    session.close()


def test_node_publishes_versions_and_plans_with_the_latest(
    bus: tuple[str, PlannerNode], nominal: System, truth: System
) -> None:
    endpoint, node = bus
    keys = Keys(PREFIX)
    raw = raw_session(endpoint)
    inbox = Inbox(raw, keys.calibration)
    try:
        with PlanClient(endpoint=endpoint, prefix=PREFIX) as client:
            assert client.wait_for_node("planner", 10.0)
            target = AIM + np.array([0.01, -0.02, 0.0])
            before = client.request(make_request([target]))
            assert before["metrics"]["extra"]["calibration_version"] == 0
            assert node.online is not None and len(node.online._planned) == 1  # its hit counts
            # the rest sampler over the bus: joints at rest and frames of a spot
            assert nominal.camera is not None
            spot_w = BeamModel(truth).trace(nominal.home).spot
            p_cam = transform_points(inv_T(nominal.camera.world_T_camera), spot_w)
            js = JointState(t=time.time(), names=[f"j{i}" for i in range(6)],
                            q=nominal.home.tolist(), qd=[0.0] * 6)  # fmt: skip
            for _ in range(4):  # one sample however many frames at this rest configuration
                raw.put(keys.joint_states("arm0"), encode(js))
                time.sleep(0.05)
                raw.put(
                    keys.camera_spot,
                    encode(SpotMessage(t=time.time(), p_camera=p_cam.tolist(), confidence=1.0)),
                )
                time.sleep(0.05)
            raw.put(keys.camera_spot, b"\xff not json")
            raw.put(keys.camera_spot, b'{"schema": "beamrelay.spot/1", "t": 1, "p_camera": [1, 2]}')
            wait_for(
                lambda: node.online is not None and node.online.n_samples == 1, 5.0, "a sample"
            )
            # the servo's API
            q, spots, boards = true_samples(truth, 12, seed=2)
            assert node.online is not None
            for qk, sk, b in zip(q, spots, boards, strict=True):
                node.online.add_sample({"arm0": qk}, sk, surface=b)
            assert node.online.wait_idle(120)
            version = node.online.current.version
            assert version >= 1

            def latest() -> bool:
                return any(b.get("version") == version for b in inbox.bodies())

            wait_for(latest, 5.0, "the latest calibration message")
            last = CalibrationMessage.model_validate(inbox.bodies()[-1])
            assert last.version == node.online.current.version == node.calibration_version >= 1
            after = client.request(make_request([target]))
    finally:
        inbox.close()
        raw.close()
    assert after["metrics"]["extra"]["calibration_version"] == last.version
    sol = after["solutions"][0]
    assert sol["status"] == "ok"
    # planned with the refined model, the TRUE beam lands on the target
    q_after = np.asarray(sol["q"]["arm0"])
    err_after = BeamModel(truth).trace(q_after, target).error
    q_before = np.asarray(before["solutions"][0]["q"]["arm0"])
    err_before = BeamModel(truth).trace(q_before, target).error
    assert err_before > 1e-3 and err_after < 1e-6


def test_a_request_in_progress_keeps_its_calibration(nominal: System) -> None:
    """install_calibration during serve: that request reports the version it started with."""
    from planner.service.handler import RequestHandler, make_plan_fn

    started, release = threading.Event(), threading.Event()
    inner = make_plan_fn(nominal, {"name": "t"})

    def slow(targets: Any, start: Any, traj: bool, dwell: float | None = None,
             rate: float | None = None) -> dict[str, Any]:  # fmt: skip
        started.set()
        release.wait(10)
        return inner(targets, start, traj, dwell)

    node = PlannerNode(RequestHandler(nominal, slow), session=None,
                       online=OnlineCalibrator(nominal, Path("unused.yaml")))  # fmt: skip
    body = encode(make_request([AIM]))
    out: dict[str, Any] = {}
    t = threading.Thread(target=lambda: out.update(plan=node.serve(body)))
    t.start()
    assert started.wait(10)
    node.install_calibration(RequestHandler(nominal, inner), type("C", (), {"version": 7})())
    release.set()
    t.join(10)
    import json

    assert json.loads(out["plan"])["metrics"]["extra"]["calibration_version"] == 0
    assert json.loads(node.serve(body))["metrics"]["extra"]["calibration_version"] == 7


def test_a_camera_spot_far_from_the_modelled_beam_is_dropped_and_counted(
    tmp_path: Path, scenario: Path, nominal: System, truth: System
) -> None:
    """The truth's spots (a few mm from the nominal beam) are taken; the same spots moved
    100 mm sideways (a reflection, another light) are dropped as implausible."""
    from planner.service.online import MAX_RAY_DISTANCE, ray_distance

    cal, _ = calibrator(nominal, scenario, tmp_path / "online.yaml")
    q, spots, _ = true_samples(truth, 4, seed=2)
    assert nominal.camera is not None
    camera_T_world = np.linalg.inv(nominal.camera.world_T_camera)
    for qk, sk in zip(q, spots, strict=True):
        assert ray_distance(nominal, qk, sk) < 0.01  # a real spot: mm from the model's beam
        far = sk + np.array([0.1, 0.0, 0.0])
        assert ray_distance(nominal, qk, far) > MAX_RAY_DISTANCE
        assert not cal.add_camera_spot(qk, camera_T_world[:3, :3] @ far + camera_T_world[:3, 3])
        assert cal.add_camera_spot(qk, camera_T_world[:3, :3] @ sk + camera_T_world[:3, 3])
    assert cal.implausible == len(q) and cal.n_samples == len(q)


def _poses(system: System) -> tuple[np.ndarray, np.ndarray]:
    return system.world_T_laser, system.robots[0].mirror.flange_T_mirror


def test_every_version_is_kept_and_logged_and_one_command_rolls_a_refit_back(
    tmp_path: Path,
    scenario: Path,
    nominal: System,
    truth: System,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Refits keep every version in FILE.versions/ and log one line each with their
    figures; `beamrelay calibrate rollback FILE` (a real process) makes a new version with
    the previous poses, which the running calibrator installs, publishes and starts over
    from; `--to 0` goes back to the scenario's own calibration; bad rollbacks exit 2."""
    import subprocess
    import sys

    from planner.service.online_file import history, read_document, system_of, version_of
    from tests.cli_run import assert_usage_error, beamrelay

    out = tmp_path / "online.yaml"
    cal, bodies = calibrator(nominal, scenario, out)
    installed: list[Any] = []
    cal.on_update = lambda h, c: installed.append(h)
    caplog.set_level("INFO", logger="beamrelay.online")
    cal.start()
    try:
        q, spots, boards = true_samples(truth, 12)
        for qk, sk, b in zip(q, spots, boards, strict=True):  # one refit attempt each
            assert cal.add_sample({"arm0": qk}, sk, surface=b)
            assert cal.wait_idle(120)
        top = cal.current.version
        kept = history(out)
        assert top >= 2 and sorted(kept) == list(range(top + 1)), caplog.messages
        # version 0: the calibration in force before the first refit (the scenario's)
        v0 = read_document(kept[0])
        for a, b in zip(_poses(system_of(v0, nominal)), _poses(nominal), strict=True):
            np.testing.assert_allclose(a, b, atol=1e-12)
        lines = [r.getMessage() for r in caplog.records]
        accepted = [m for m in lines if m.startswith("refit_accepted")]
        refused = [m for m in lines if m.startswith("refit_refused")]
        assert len(accepted) == top and len(accepted) + len(refused) == cal.refits
        assert "surface.board0=" in accepted[0] and "margin_mm=" in accepted[0]
        assert sum("at least 7" in m for m in refused) == 6  # the first six samples
        assert any("1 surface(s)" in m for m in refused)  # the seventh: one on board1
        before = read_document(kept[top - 1])

        ran = subprocess.run([sys.executable, "-m", "planner.cli", "calibrate", "rollback",
                              str(out)], capture_output=True, text=True, timeout=60)  # fmt: skip
        assert ran.returncode == 0, ran.stderr
        assert f"version {top + 1} = version {top - 1} (was {top})" in ran.stdout
        wait_for(lambda: cal.current.version == top + 1, 10, "the rollback installed")
        for a, b in zip(_poses(cal.current.system), _poses(system_of(before, nominal)),
                        strict=True):  # fmt: skip
            np.testing.assert_allclose(a, b, atol=1e-12)
        assert cal.n_samples == 0 and installed[-1] is not None
        np.testing.assert_allclose(installed[-1].system.world_T_laser,
                                   cal.current.system.world_T_laser, atol=1e-12)  # fmt: skip
        assert CalibrationMessage.model_validate_json(bodies[-1]).version == top + 1
        assert any(r.getMessage().startswith(f"calibration_rolled_back version={top + 1}"
                   f" to={top - 1} was={top}") for r in caplog.records)  # fmt: skip

        ran2 = beamrelay("calibrate", "rollback", out, "--to", "0")
        assert ran2.returncode == 0, ran2.stderr
        wait_for(lambda: cal.current.version == top + 2, 10, "the rollback to 0 installed")
        for a, b in zip(_poses(cal.current.system), _poses(nominal), strict=True):
            np.testing.assert_allclose(a, b, atol=1e-12)
        assert version_of(read_document(out)) == top + 2 and sorted(history(out))[-1] == top + 2
        # a new refit after a rollback is numbered after every kept version
        for qk, sk, b in zip(q, spots, boards, strict=True):
            cal.add_sample({"arm0": qk}, sk, surface=b)
        assert cal.wait_idle(120) and cal.current.version > top + 2
    finally:
        cal.close()
    assert_usage_error(beamrelay("calibrate", "rollback", out, "--to", "99"), "no version 99",
                       "kept: 0, 1")  # fmt: skip
    assert beamrelay("calibrate", "rollback", out, "--to", "-1").returncode == 2
    assert_usage_error(beamrelay("calibrate", "rollback", scenario), "not a file written by"
                       " the online calibration")  # fmt: skip
    assert_usage_error(beamrelay("calibrate", "rollback", tmp_path / "nope.yaml"), "nope.yaml")
    fresh = tmp_path / "fresh.yaml"  # a version-1 file whose history went missing
    fresh.write_text(out.read_text())
    assert_usage_error(beamrelay("calibrate", "rollback", fresh), "no kept versions")


def test_samples_are_labelled_by_the_scene_object_they_lie_on_and_plans_are_remembered(
    tmp_path: Path, scenario: Path, nominal: System
) -> None:
    from planner.io.scenario import scene_model

    scene = scene_model(load_scenario(scenario))
    cal, _ = calibrator(nominal, scenario, tmp_path / "o.yaml", scene=scene)
    on_board = AIM  # the board's top face (z -0.06)
    assert cal.surface_of(on_board) == "board"
    assert cal.surface_of(on_board + np.array([0, 0, 0.009])) == "board"
    assert cal.surface_of(on_board + np.array([0, 0, 0.05])) == ""  # in the air
    assert cal.add_sample({"arm0": nominal.home}, on_board)
    assert cal._samples[-1].surface == "board"
    assert cal.add_sample({"arm0": nominal.home}, on_board, surface="table")
    assert cal._samples[-1].surface == "table"
    plan = as_plan({"targets": [{"id": k, "p": [0.0, 0.0, 0.0]} for k in range(4)],
                    "solutions": [
        {"target": 0, "status": "ok", "q": {"arm0": nominal.home.tolist()}},
        {"target": 1, "status": "failed", "reason": "unreachable",
         "q": {"arm0": nominal.home.tolist()}},
        {"target": 2, "status": "ok", "q": {"arm0": [0.0] * 3}},
        {"target": 3, "status": "ok", "q": None},
    ]})  # fmt: skip
    assert cal.add_planned(plan) == 1 and cal.add_planned(as_plan({})) == 0


def _refit_versions(cal: OnlineCalibrator, truth: System, n: int, seed: int) -> None:
    """Feed ``n`` exact samples on two boards, one refit attempt each."""
    q, spots, boards = true_samples(truth, n, seed=seed)
    for qk, sk, b in zip(q, spots, boards, strict=True):
        assert cal.add_sample({"arm0": qk}, sk, surface=b)
        assert cal.wait_idle(120)


def test_default_rollbacks_walk_back_through_refits_never_forward(
    tmp_path: Path, scenario: Path, nominal: System, truth: System
) -> None:
    """refits 1..k, rollback (to k-1), refits, rollback, rollback: each default rollback
    undoes one more refit (the one whose poses are in force, found through the rollback
    links); none brings back a version that was rolled back."""
    from planner.service.online_file import history, read_document, rollback

    out = tmp_path / "online.yaml"
    cal, _ = calibrator(nominal, scenario, out)
    cal.start()
    try:
        _refit_versions(cal, truth, 12, seed=3)
        top = cal.current.version
        prev = read_document(history(out)[top])["report"]["online"]["previous_version"]
        assert rollback(out) == (top + 1, prev, top)
        wait_for(lambda: cal.current.version == top + 1, 10, "the rollback installed")
        _refit_versions(cal, truth, 12, seed=4)  # new samples refit from the rolled-back one
        refit_v = cal.current.version
        assert refit_v > top + 1
        _, to, was = rollback(out)  # undoes that refit
        assert (to, was) == (read_document(history(out)[refit_v])["report"]["online"][
            "previous_version"], refit_v)  # fmt: skip
        _, to2, _ = rollback(out)  # one more: the refit whose poses those are, undone
        assert to2 == read_document(history(out)[to])["report"]["online"]["previous_version"]
        assert to2 < to and to2 not in (refit_v, top)  # never forward to an undone version
    finally:
        cal.close()


def test_a_rollback_written_during_a_refit_wins(
    tmp_path: Path, scenario: Path, nominal: System, truth: System
) -> None:
    """A rollback that lands while a refit runs: the refit is dropped (logged), FILE and the
    history keep the rollback, and the calibrator installs it."""
    from planner.service import online as online_mod
    from planner.service.online_file import history, read_document, rollback, version_of

    out = tmp_path / "online.yaml"
    cal, _ = calibrator(nominal, scenario, out)
    cal.start()
    try:
        _refit_versions(cal, truth, 10, seed=5)
        top = cal.current.version
        assert top >= 2
        real_refit = online_mod.refit

        def slow_refit(*args: Any, **kw: Any) -> Any:
            result = real_refit(*args, **kw)
            rollback(out, 0)  # the operator's command, while this refit is being decided
            return result

        online_mod.refit = slow_refit  # type: ignore[assignment]
        try:
            result = cal.refit_now(list(cal._samples))
        finally:
            online_mod.refit = real_refit  # type: ignore[assignment]
        assert not result.accepted and "changed during the refit" in result.reason
        doc = read_document(out)
        assert doc["report"]["online"]["rolled_back_to"] == 0
        assert version_of(doc) == max(history(out)) == top + 1
        assert cal.check_rollback() and cal.current.version == top + 1 and cal.n_samples == 0
    finally:
        cal.close()


def test_a_restarted_planner_resumes_the_version_in_its_file(
    tmp_path: Path, scenario: Path, nominal: System, truth: System
) -> None:
    """A new calibrator on an existing FILE (the planner restarted by up's supervisor) goes
    on with FILE's version and poses, and numbers its next refit after the history."""
    out = tmp_path / "online.yaml"
    first, _ = calibrator(nominal, scenario, out)
    first.start()
    try:
        _refit_versions(first, truth, 10, seed=6)
    finally:
        first.close()
    again, _ = calibrator(nominal, scenario, out)
    assert again.resume()
    assert again.current.version == first.current.version
    for a, b in zip(_poses(again.current.system), _poses(first.current.system), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)
    broken, _ = calibrator(nominal, scenario, tmp_path / "missing.yaml")
    assert not broken.resume() and broken.current.version == 0


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda d: d["report"]["online"].update(version="abc"), "report.online.version"),
        (lambda d: d["report"]["online"].pop("version"), "version is missing"),
        (lambda d: d["report"]["online"].update(version=True), "report.online.version"),
        (lambda d: d["report"]["online"].update(rolled_back_to=None), "rolled_back_to"),
        (lambda d: d["report"]["online"].update(previous_version=-3), "previous_version"),
    ],
)
def test_hostile_online_files_are_refused_in_one_line(
    tmp_path: Path, scenario: Path, nominal: System, truth: System, edit: Any, words: str
) -> None:
    from ruamel.yaml import YAML

    from tests.cli_run import assert_usage_error, beamrelay

    out = tmp_path / "online.yaml"
    cal, _ = calibrator(nominal, scenario, out)
    cal.start()
    try:
        _refit_versions(cal, truth, 9, seed=7)
    finally:
        cal.close()
    yaml = YAML(typ="safe", pure=True)
    doc = yaml.load(out.read_text())
    edit(doc)
    with out.open("w") as fh:
        yaml.dump(doc, fh)
    assert_usage_error(beamrelay("calibrate", "rollback", out), words)
    # and a history whose target holds no poses: refused, nothing written
    from planner.service.online_file import history

    out.write_text((history(out)[max(history(out))]).read_text())
    (history(out)[0]).write_text("report: {online: {version: 0}}\n")
    before = sorted(history(out))
    assert_usage_error(beamrelay("calibrate", "rollback", out, "--to", "0"), "no mirror pose")
    assert sorted(history(out)) == before
