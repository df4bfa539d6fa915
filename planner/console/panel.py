"""The console's GUI widgets (viser handles), built in one place, no behaviour.

Order on the page: the large Stop button, system health, the target list and its edits,
plan / execute and their results, the trajectory scrubber, then the calibration wizard.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner.calibration.collect import SPEED, SPEED_RANGE
from planner.console.targets import Mode


@dataclass(frozen=True)
class Panel:
    """Handles of every widget."""

    stop: Any
    health: Any
    targets: Any
    selected: Any
    up: Any
    down: Any
    delete: Any
    clear: Any
    mode: Any
    normals: Any
    auto_preview: Any
    plan: Any
    dwell: Any
    closed_loop: Any
    arm: Any
    execute: Any
    result: Any
    scrub: Any
    live: Any
    stats: Any


def build_panel(server: Any) -> Panel:
    """Add the widgets to the GUI of ``server`` (a viser server or one client's handle)."""
    gui = server.gui
    stop = gui.add_button("STOP", color="red", icon=None, hint="Publish beamrelay/stop: "
                          "every robot brakes, laser off (or press the space bar)")  # fmt: skip
    with gui.add_folder("System"):
        health = gui.add_markdown("waiting for the bus...")
    with gui.add_folder("Targets"):
        targets = gui.add_markdown("no targets: click the point cloud to add one")
        selected = gui.add_number("target #", 0, min=0, step=1)
        up = gui.add_button("Move up")
        down = gui.add_button("Move down")
        delete = gui.add_button("Delete")
        clear = gui.add_button("Clear all")
        mode = gui.add_dropdown(
            "visit as", [m.value for m in Mode], initial_value=Mode.POINTS.value
        )
        normals = gui.add_checkbox("use fitted normals", True)
        auto_preview = gui.add_checkbox("preview on click", True)
    with gui.add_folder("Plan and execute"):
        plan = gui.add_button("Plan (preview)")
        dwell = gui.add_number("dwell [s]", 0.4, min=0.0, max=10.0, step=0.1)
        closed_loop = gui.add_checkbox("closed loop", False)
        arm = gui.add_button("Arm", color="orange", hint="Preview and show what Execute will "
                             "do; Execute then runs exactly that, once, within 30 s")  # fmt: skip
        execute = gui.add_button("Execute", color="green", hint="Runs what was armed")
        result = gui.add_markdown("")
        scrub = gui.add_slider("scrub t [s]", 0.0, 1.0, 0.01, 0.0, disabled=True)
        live = gui.add_button("Follow live robots")
    with gui.add_folder("View"):
        stats = gui.add_markdown("")
    return Panel(stop, health, targets, selected, up, down, delete, clear, mode, normals,
                 auto_preview, plan, dwell, closed_loop, arm, execute, result, scrub, live,
                 stats)  # fmt: skip


#: the wizard's place on the page: after the widgets of :func:`build_panel`
WIZARD_ORDER = 1e9


@dataclass(frozen=True)
class CalibrationPanel:
    """Handles of the calibration wizard's widgets."""

    kind: Any
    poses: Any
    speed: Any
    aim: Any
    dataset: Any
    output: Any
    collect: Any
    calibrate: Any
    cancel: Any
    log: Any


def build_calibration_panel(server: Any, kinds: tuple[str, ...], aim: str, workdir: Path,
                            files: tuple[str, str]) -> CalibrationPanel:  # fmt: skip
    """The wizard's widgets (collapsed): ``kinds`` of calibration (the first chosen),
    ``aim`` the default board centre text, ``workdir`` the working directory the file names
    are relative to (shown), ``files`` the first kind's default dataset and output names."""

    gui = server.gui
    # below every browser's own panel, which is built later, when the browser connects
    with gui.add_folder("Calibration wizard", expand_by_default=False, order=WIZARD_ORDER):
        kind = gui.add_dropdown("calibration", list(kinds), initial_value=kinds[0])
        poses = gui.add_number("poses", 12, min=3, max=200, step=1)
        speed = gui.add_number("speed [rad/s]", SPEED, min=SPEED_RANGE[0], max=SPEED_RANGE[1],
                               step=0.01)  # fmt: skip
        aim_h = gui.add_text("board centre (beam) [m]", aim)
        gui.add_markdown(f"files in `{workdir}` unless a path is absolute")
        dataset = gui.add_text("dataset", files[0])
        output = gui.add_text("calibration file", files[1])
        collect = gui.add_button("1. Collect data (moves the robot)")
        calibrate = gui.add_button("2. Calibrate and write the file")
        cancel = gui.add_button("Cancel step")
        log = gui.add_markdown("")
    return CalibrationPanel(kind, poses, speed, aim_h, dataset, output, collect, calibrate, cancel,
                            log)  # fmt: skip
