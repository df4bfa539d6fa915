"""``beamrelay calibrate``: simulate -> calibrate -> YAML, and one-line errors (exit 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ruamel.yaml import YAML

from planner.cli import main
from planner.io.scenario import load_scenario, system_from_scenario

from .cal_systems import write_scenario


def _run(argv):
    try:
        main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code
    return 0


def _simulate(scn, out, *options):
    """``beamrelay calibrate simulate SCN OPTIONS -o OUT``; its exit status."""
    return _run(["calibrate", "simulate", scn, *options, "-o", out])


def test_simulate_then_calibrate_beam(tmp_path, capsys):
    scn = tmp_path / "scn.yaml"
    write_scenario(scn)
    data, out = tmp_path / "beam.json", tmp_path / "cal.yaml"
    assert _simulate(scn, data, "--kind", "beam", "--poses", "6", "--noise", "none") == 0
    assert len(json.loads(data.read_text())["samples"]) == 18
    assert _run(["calibrate", "beam", data, "--scenario", scn, "-o", out]) == 0
    doc = YAML(typ="safe").load(out.read_text())
    assert doc["report"]["residuals"]["max"] < 1e-9
    truth = system_from_scenario(load_scenario(scn), truth=True)
    n_true = truth.robots[0].mirror.flange_T_mirror[:3, 2]
    assert np.allclose(doc["report"]["calibrated"]["mirror_plane"]["normal"], n_true, atol=1e-9)
    assert "not calibrated: laser.tz" in capsys.readouterr().out


@pytest.mark.parametrize("mode", ["eye_to_hand", "eye_in_hand"])
def test_simulate_then_calibrate_handeye(tmp_path, mode):
    scn = tmp_path / "scn.yaml"
    write_scenario(scn)
    data, out = tmp_path / "he.json", tmp_path / "he.yaml"
    assert _simulate(scn, data, "--kind", "handeye", "--mode", mode, "--poses", "8") == 0
    assert _run(["calibrate", "handeye", data, "-s", scn, "-o", out, "--loss", "huber"]) == 0
    doc = YAML(typ="safe").load(out.read_text())
    assert doc["report"]["mode"] == mode
    mount = {"world_T_camera"} if mode == "eye_to_hand" else {"robot", "flange_T_camera"}
    assert set(doc["system"]["camera"]) == mount
    assert 0 < doc["report"]["residuals"]["mean"] < 0.01  # D435 noise, metres


def test_user_mistakes_exit_2_with_one_line(tmp_path, capsys):
    scn = tmp_path / "scn.yaml"
    write_scenario(scn)
    data = tmp_path / "beam.json"
    _simulate(scn, data, "--kind", "beam", "--poses", "2", "--boards", "1", "--noise", "none")
    capsys.readouterr()
    cases = [
        (["calibrate", "beam", data, "-s", scn, "--loss", "tukey"], "--loss"),
        (["calibrate", "beam", data, "-s", scn], "need at least 4 spots"),
        (["calibrate", "handeye", data, "-s", scn], "schema"),
        (["calibrate", "simulate", scn, "--kind", "laser"], "--kind"),
        (["calibrate", "beam", tmp_path / "none.json", "-s", scn], "not found"),
    ]
    for argv, text in cases:
        assert _run(argv) == 2
        err = capsys.readouterr().err.strip()
        assert text in err and len(err.splitlines()) == 1 and "Traceback" not in err
