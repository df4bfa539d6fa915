"""The calibration wizard: collect data on the running system, calibrate, show the report.

Two steps per calibration kind, each one run of the project's own commands as a subprocess
(their public entry points, with this console's bus options): *collect*
(``beamrelay calibrate collect handeye|beam``: the robot visits well-conditioned poses, the
camera measures the board's markers or the laser spot) writes the dataset; *calibrate*
(``beamrelay calibrate handeye|beam``) fits it and writes the calibration YAML, whose
``report:`` (residuals, parameter standard deviations, unobservable directions) the wizard
shows. One step runs at a time; its output is shown as it arrives.

Both files go to the console's working directory (``beamrelay console --workdir``, ``up
--console-workdir``; default ``$XDG_DATA_HOME/beamrelay/console``, i.e.
``~/.local/share/beamrelay/console``, created when a step first needs it), never the
repository or the scenario's folder: a relative path typed in the wizard is taken relative
to it (:mod:`planner.console.workdir`). A mistake in a field (a directory, a folder that
cannot be made or written) is one line in the wizard's log.

A step ends with the console: closing the console sends it SIGTERM and, after
:data:`STOP_WAIT` s, SIGKILL (to its process group); a console that dies without closing
(SIGKILL, a crash) takes it along through Linux's parent-death signal (SIGTERM). A collect
step ends on SIGTERM as on Ctrl-C: its heartbeat stops, so the robot driver brakes an arm
still moving within its 0.1 s heartbeat timeout.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import queue
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML

from planner.calibration.collect import SPEED, SPEED_RANGE
from planner.console.panel import build_calibration_panel
from planner.console.workdir import default_workdir, ensure_dir, input_path, output_path
from planner.errors import BeamrelayError, InputError

KINDS = ("handeye", "beam")
#: most output lines kept for the panel
TAIL = 14
#: s a closing console waits for a step to exit after SIGTERM before SIGKILL (within the
#: 5 s ``up`` gives the console itself)
STOP_WAIT = 2.0
#: s to wait for the exit after SIGKILL
KILL_WAIT = 1.0
PR_SET_PDEATHSIG = 1  # prctl option (linux/prctl.h)


def collect_argv(kind: str, scenario: Path, dataset: Path, poses: int, aim: list[float] | None,
                 bus: list[str], speed: float = SPEED) -> list[str]:  # fmt: skip
    """argv of the collect step (``aim``: board centre in the world, m; beam only;
    ``speed``: peak joint speed of the moves, rad/s)."""
    _check(kind, poses)
    if not SPEED_RANGE[0] <= speed <= SPEED_RANGE[1]:
        raise InputError(f"{speed:g} rad/s: expected {SPEED_RANGE[0]:g}-{SPEED_RANGE[1]:g}",
                         "speed")  # fmt: skip
    argv = [sys.executable, "-m", "planner.cli", "calibrate", "collect", kind,
            "--scenario", str(scenario), "-o", str(dataset), "--poses", str(poses)]  # fmt: skip
    argv += [] if speed == SPEED else ["--speed", f"{speed:g}"]
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
    """Runs one command at a time, feeding its output lines to ``show``.

    The command runs in its own process group and, on Linux, gets SIGTERM when this process
    dies (``PR_SET_PDEATHSIG``): a step never outlives the console. The thread that starts
    the command also reads its output and waits for it, so it lives as long as the command
    (Linux sends the parent-death signal when the *thread* that forked the child ends)."""

    def __init__(self, show: Callable[[str], None]) -> None:
        self.show = show
        self.proc: subprocess.Popen[str] | None = None
        self._lock = threading.Lock()
        self._closed = False

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def run(self, argv: list[str], done: Callable[[int], Any] | None = None) -> None:
        """Start ``argv`` in the background; InputError if a step is still running, the
        runner is closed or the command cannot start."""
        with self._lock:
            if self._closed:
                raise InputError("the console is closing", "calibration")
            if self.running:
                raise InputError("a calibration step is still running", "calibration")
            started: queue.Queue[subprocess.Popen[str] | OSError] = queue.Queue()
            threading.Thread(target=self._follow, args=(argv, started, done), daemon=True,
                             name="wizard-step").start()  # fmt: skip
            got = started.get()
            if isinstance(got, OSError):
                raise InputError(f"cannot start {argv[0]}: {got.strerror}", "calibration")
            self.proc = got

    def _follow(self, argv: list[str], started: queue.Queue[Any],
                done: Callable[[int], Any] | None) -> None:  # fmt: skip
        try:
            proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, text=True, start_new_session=True,
                                    preexec_fn=_die_with(os.getpid()))  # fmt: skip
        except OSError as exc:
            started.put(exc)
            return
        started.put(proc)
        lines: list[str] = []
        assert proc.stdout is not None
        for line in proc.stdout:
            lines = [*lines, line.rstrip()][-TAIL:]
            self.show("\n".join(f"    {x}" for x in lines))
        code = proc.wait()
        if done is not None:
            done(code)

    def cancel(self) -> None:
        """SIGTERM to the running step's process group (returns at once)."""
        self._signal(signal.SIGTERM)

    def close(self, timeout: float = STOP_WAIT) -> int | None:
        """Refuse new steps; end the running one: SIGTERM, then SIGKILL when it has not
        exited after ``timeout`` s. Its exit status (None: none ran)."""
        with self._lock:
            self._closed = True
        proc = self.proc
        if proc is None:
            return None
        self._signal(signal.SIGTERM)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self._signal(signal.SIGKILL)
            return proc.wait(KILL_WAIT)

    def _signal(self, sig: int) -> None:
        proc = self.proc
        if proc is not None and proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, sig)  # the step's own group: its children too


def _die_with(parent: int) -> Callable[[], None]:
    """The child's pre-exec hook: SIGTERM when ``parent`` dies (Linux), and exit at once if
    it died before the request was made."""
    prctl = _prctl()

    def hook() -> None:  # pragma: no cover - runs in the child between fork and exec
        if prctl is not None:
            prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:
            os._exit(1)

    return hook


def _prctl() -> Any:
    """libc's ``prctl`` (looked up here, in the parent: the child only calls it), or None
    off Linux."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def files(kind: str) -> tuple[str, str]:
    """The default dataset and calibration file names of calibration ``kind`` (relative to
    the working directory)."""
    return f"{kind}_data.json", f"{kind}.yaml"


class Wizard:
    """The wizard's panel on ``server`` and its steps: collect, calibrate, cancel (one
    :class:`StepRunner`); ``bus``: the console's bus options (endpoint, prefix, zenoh_config);
    ``workdir``: where its files go (default :func:`~planner.console.workdir.default_workdir`,
    created when a step first needs it)."""

    def __init__(self, server: Any, scenario: Path, scene_items: list[Any],
                 bus: dict[str, Any], workdir: Path | None = None) -> None:  # fmt: skip
        self.scenario, self.bus = scenario, bus
        self.workdir = Path(workdir).absolute() if workdir is not None else default_workdir()
        centre = scene_items[0].world_T_object[:3, 3] if scene_items else [0, 0, 0]
        aim = ",".join(f"{v:.3f}" for v in centre)
        self.cal = build_calibration_panel(server, KINDS, aim, self.workdir, files(KINDS[0]))
        self.cal.kind.on_update(lambda _: self.kind_changed())
        self.steps = StepRunner(lambda text: setattr(self.cal.log, "content", text))
        self.cal.collect.on_click(lambda _: self.collect())
        self.cal.calibrate.on_click(lambda _: self.calibrate())
        self.cal.cancel.on_click(lambda _: self.steps.cancel())

    def kind_changed(self) -> None:
        """Another calibration kind chosen: file names still at another kind's defaults take
        this kind's (so a beam calibration never overwrites the hand-eye files); names the
        operator typed stay."""
        dataset, output = files(str(self.cal.kind.value))
        if str(self.cal.dataset.value) in {files(k)[0] for k in KINDS}:
            self.cal.dataset.value = dataset
        if str(self.cal.output.value) in {files(k)[1] for k in KINDS}:
            self.cal.output.value = output

    def close(self) -> None:
        """End a running step (SIGTERM, SIGKILL after :data:`STOP_WAIT` s) and refuse more."""
        self.steps.close()

    def collect(self) -> None:
        """What "1. Collect data" does: start the collect step; a mistake in the fields is
        one line in the wizard's log."""
        self._run(self._collect)

    def calibrate(self) -> None:
        """What "2. Calibrate and write the file" does (mistakes: one line in the log)."""
        self._run(self._calibrate)

    def _run(self, fn: Callable[[], None]) -> None:
        try:
            fn()
        except BeamrelayError as exc:
            self.cal.log.content = f"**{_one_line(str(exc))}**"

    def _collect(self) -> None:
        kind = str(self.cal.kind.value)
        aim = parse_aim(str(self.cal.aim.value)) if kind == "beam" else None
        poses = int(self.cal.poses.value)
        _check(kind, poses)
        dataset = self._output(self.cal.dataset.value, "dataset", (".json",))
        argv = collect_argv(kind, self.scenario, dataset, poses, aim, bus_options(**self.bus),
                            float(self.cal.speed.value))  # fmt: skip
        self.steps.run(argv)

    def _calibrate(self) -> None:
        kind = str(self.cal.kind.value)
        _check(kind, 3)
        dataset = input_path(self.workdir, str(self.cal.dataset.value), "dataset")
        if not dataset.is_file():
            raise InputError(f"no dataset at {dataset}: run step 1 first", "dataset")
        out = self._output(self.cal.output.value, "calibration file", (".yaml", ".yml"))
        argv = calibrate_argv(kind, self.scenario, dataset, out)

        def done(code: int) -> None:
            if code in (0, 1) and out.is_file():
                self.cal.log.content += "  \n" + report_markdown(out)

        self.steps.run(argv, done)

    def _output(self, text: Any, field: str, suffixes: tuple[str, ...]) -> Path:
        ensure_dir(self.workdir, "working directory")
        return output_path(self.workdir, str(text), field, suffixes)


def _one_line(text: str) -> str:
    return "; ".join(line.strip() for line in text.splitlines() if line.strip())
