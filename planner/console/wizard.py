"""The calibration wizard: collect data on the running system, calibrate, show the report.

Two steps per calibration kind, each one run of the project's own commands as a subprocess
(their public entry points, with this console's bus options): *collect*
(``beamrelay calibrate collect handeye|beam``: the robot visits well-conditioned poses, the
camera measures the board's markers or the laser spot) writes the dataset; *calibrate*
(``beamrelay calibrate handeye|beam``) fits it and writes the calibration YAML, whose
``report:`` (residuals, parameter standard deviations, unobservable directions) the wizard
shows. One step runs at a time; its output is shown as it arrives.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from planner.errors import BeamrelayError, InputError

KINDS = ("handeye", "beam")
#: most output lines kept for the panel
TAIL = 14


def collect_argv(kind: str, scenario: Path, dataset: Path, poses: int, aim: list[float] | None,
                 bus: list[str]) -> list[str]:  # fmt: skip
    """argv of the collect step (``aim``: board centre in the world, m; beam only)."""
    _check(kind, poses)
    argv = [sys.executable, "-m", "planner.cli", "calibrate", "collect", kind,
            "--scenario", str(scenario), "-o", str(dataset), "--poses", str(poses)]  # fmt: skip
    if kind == "beam":
        if aim is None or len(aim) != 3:
            raise InputError("the beam step needs the board centre X,Y,Z (m)", "aim")
        argv += ["--aim", ",".join(f"{v:g}" for v in aim)]
    return argv + bus


def calibrate_argv(kind: str, scenario: Path, dataset: Path, output: Path) -> list[str]:
    """argv of the calibrate step."""
    _check(kind, 3)
    return [sys.executable, "-m", "planner.cli", "calibrate", kind, str(dataset),
            "--scenario", str(scenario), "-o", str(output)]  # fmt: skip


def bus_options(endpoint: str | None, prefix: str, zenoh_config: Path | None) -> list[str]:
    out = [] if endpoint is None else ["--endpoint", endpoint]
    out += [] if prefix == "beamrelay" else ["--prefix", prefix]
    return out + ([] if zenoh_config is None else ["--zenoh-config", str(zenoh_config)])


def parse_aim(text: str) -> list[float]:
    """``X,Y,Z`` (m) of the board centre; InputError otherwise."""
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"{text!r}: expected X,Y,Z numbers (m)", "board centre") from None
    if len(v) != 3 or not all(abs(x) < 100 for x in v):
        raise InputError(f"{text!r}: expected X,Y,Z (3 numbers, |x| < 100 m)", "board centre")
    return v


def report_markdown(calibration_yaml: Path) -> str:
    """The ``report:`` of a calibration file: residuals (mm) and parameter deviations."""
    from ruamel.yaml import YAML

    doc = YAML(typ="safe").load(calibration_yaml.read_text())
    report = (doc or {}).get("report") or {}
    lines = [f"**wrote {calibration_yaml}**"]
    for key, value in report.items():
        text = str(value)
        lines.append(f"{key}: `{text[:240]}`")
    return "  \n".join(lines)


def _check(kind: str, poses: int) -> None:
    if kind not in KINDS:
        raise InputError(f"unknown calibration {kind!r}: expected {' or '.join(KINDS)}", "kind")
    if not 3 <= poses <= 200:
        raise InputError(f"poses {poses}: expected 3-200", "poses")


class StepRunner:
    """Runs one command at a time, feeding its output lines to ``show``."""

    def __init__(self, show: Callable[[str], None]) -> None:
        self.show = show
        self.proc: subprocess.Popen[str] | None = None
        self._lock = threading.Lock()

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def run(self, argv: list[str], done: Callable[[int], Any] | None = None) -> None:
        """Start ``argv`` in the background; InputError if a step is still running."""
        with self._lock:
            if self.running:
                raise InputError("a calibration step is still running", "calibration")
            self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, text=True)  # fmt: skip
        threading.Thread(target=self._follow, args=(self.proc, done), daemon=True).start()

    def _follow(self, proc: subprocess.Popen[str], done: Callable[[int], Any] | None) -> None:
        lines: list[str] = []
        assert proc.stdout is not None
        for line in proc.stdout:
            lines = [*lines, line.rstrip()][-TAIL:]
            self.show("\n".join(f"    {x}" for x in lines))
        code = proc.wait()
        if done is not None:
            done(code)

    def cancel(self) -> None:
        if self.running and self.proc is not None:
            self.proc.terminate()


class Wizard:
    """The wizard's panel on ``server`` and its steps: collect, calibrate, cancel (one
    :class:`StepRunner`); ``bus``: the console's bus options (endpoint, prefix, zenoh_config)."""

    def __init__(self, server: Any, scenario: Path, scene_items: list[Any],
                 bus: dict[str, Any]) -> None:  # fmt: skip
        from planner.console.panel import build_calibration_panel

        self.scenario, self.bus = scenario, bus
        centre = scene_items[0].world_T_object[:3, 3] if scene_items else [0, 0, 0]
        aim = ",".join(f"{v:.3f}" for v in centre)
        self.cal = build_calibration_panel(server, aim, str(scenario.parent))
        self.steps = StepRunner(lambda text: setattr(self.cal.log, "content", text))
        self.cal.collect.on_click(lambda _: self._run(self._collect))
        self.cal.calibrate.on_click(lambda _: self._run(self._calibrate))
        self.cal.cancel.on_click(lambda _: self.steps.cancel())

    def close(self) -> None:
        """End a running step."""
        self.steps.cancel()

    def _run(self, fn: Callable[[], None]) -> None:
        try:
            fn()
        except BeamrelayError as exc:
            self.cal.log.content = f"**{exc}**"

    def _collect(self) -> None:
        kind = str(self.cal.kind.value)
        aim = parse_aim(str(self.cal.aim.value)) if kind == "beam" else None
        argv = collect_argv(kind, self.scenario, Path(self.cal.dataset.value),
                            int(self.cal.poses.value), aim, bus_options(**self.bus))  # fmt: skip
        self.steps.run(argv)

    def _calibrate(self) -> None:
        out = Path(self.cal.output.value)
        argv = calibrate_argv(
            str(self.cal.kind.value), self.scenario, Path(self.cal.dataset.value), out
        )

        def done(code: int) -> None:
            if code in (0, 1) and out.is_file():
                self.cal.log.content += "  \n" + report_markdown(out)

        self.steps.run(argv, done)
