"""``study all``: each study at its TRIALS, calibration figures passed to tracking, index."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from planner.studies import all as study_all
from planner.studies.tracking import CalibrationErrors

CALIB = {"handeye": {"sweep": [{"poses": 20, "rms_pos_err_mm": 0.3, "rms_rot_err_deg": 0.02}]}}
CALIB["beam"] = {"d435_spot_rms_mm": 1.2}


def test_all_runs_each_study_at_its_scale_and_links_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[tuple[str, int, Path, Any]] = []

    def fake(name: str, trials: int) -> SimpleNamespace:
        def main(t: int, seed: int, out: Path, w: Any, s: Any, err: Any = None) -> dict:
            calls.append((name, t, out, err))
            return CALIB if name == "calibration" else {"study": name}

        return SimpleNamespace(TRIALS=trials, main=main, CalibrationErrors=CalibrationErrors)

    trials = {"ik-grid": 7, "calibration": 100, "sensitivity": 5, "mirror-sweep": 3}
    trials |= {"coverage": 2, "tracking": 10, "online": 4}
    monkeypatch.setattr(study_all, "STUDIES", {k: fake(k, n) for k, n in trials.items()})
    figures = study_all.main(1, 0, tmp_path, 1, None)
    assert [(c[0], c[1], c[2]) for c in calls] == [
        (name, trials[name], tmp_path / name) for name in study_all.ORDER
    ]
    assert tuple(trials) == study_all.ORDER  # every study, in this order
    err = next(c[3] for c in calls if c[0] == "tracking")
    assert err.camera_pos == pytest.approx(0.3e-3)
    assert err.camera_rot == pytest.approx(np.deg2rad(0.02))
    assert err.laser_pos == CalibrationErrors().laser_pos  # documented level kept
    index = (tmp_path / "index.md").read_text()
    assert "[tracking/report.md](tracking/report.md)" in index
    assert all(f"[{name}/report.md]({name}/report.md)" in index for name in trials)
    assert figures["seconds"]["tracking"] >= 0.0
