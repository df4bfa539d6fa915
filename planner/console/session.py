"""One browser's side of the console: its panel, its picks, its preview and its arming.

Every browser that opens the page gets a :class:`Session`: its own widgets (viser's
per-client GUI), its own target list, preview and answer drawn in its own scene (viser's
per-client scene), and its own arming, so what one operator picks, previews or arms is never
what another one executes. What is the same for everyone stays on the
:class:`~planner.console.app.Console`: the live cloud, robots, beam and spot, the bus, the
one request running at a time, and STOP, which any session presses for every robot and which
drops every session's arming.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.bus.events import event
from planner.console.arming import Arming, treatment
from planner.console.draw import set_lines
from planner.console.operator import Answer, BusyError
from planner.console.panel import Panel
from planner.console.picking import pick_point, surface_normal
from planner.console.preview import Preview, joints_at, preview_of
from planner.console.report import answer_markdown, late_verdict_line
from planner.console.targets import Mode, TargetList, build_request, path_points
from planner.errors import BeamrelayError, InputError
from planner.model.transforms import inv_T

if TYPE_CHECKING:
    from planner.console.app import Console

log = logging.getLogger("beamrelay.console")

#: colours outside the cloud's depth ramp (hues 50-230 deg: yellow, green, cyan, blue) and
#: apart from each other: planned beams violet, the laser-on path red
TARGET_COLOUR = (255, 140, 0)
FAILED_COLOUR = (25, 25, 25)
SWEEP_COLOUR = (255, 30, 30)
SPOT_COLOUR = (255, 0, 200)
PLANNED_BEAM_COLOUR = (170, 90, 255)


class Session:
    """One browser's panel and state (see the module docstring); ``scene``: where its
    targets and previews are drawn (the browser's own scene)."""

    def __init__(self, console: Console, panel: Panel, scene: Any) -> None:
        self.c, self.panel, self.scene = console, panel, scene
        self.targets = TargetList()
        self.preview: Preview | None = None
        self.answer: Answer | None = None
        self.arming = Arming()
        self.latency: dict[str, float] = {}
        self.waiting: dict[str, str] = {}  # robot -> request id whose verdict was not heard
        self._edit = threading.Lock()
        self._preview_wanted = threading.Event()
        self._previewing = threading.Lock()
        self._clicked_at = 0.0  # perf_counter s of the last click on the cloud

    def wire(self) -> Session:
        """Connect the panel's widgets to this session's actions."""
        p = self.panel
        p.stop.on_click(lambda _: self.do_stop())
        p.up.on_click(lambda _: self.edit_list(lambda t: t.move(self._selected(), -1)))
        p.down.on_click(lambda _: self.edit_list(lambda t: t.move(self._selected(), +1)))
        p.delete.on_click(lambda _: self.edit_list(lambda t: t.delete(self._selected())))
        p.clear.on_click(lambda _: self.edit_list(lambda t: TargetList()))
        p.mode.on_update(lambda _: self.draw_targets())
        p.plan.on_click(lambda _: self.run(self.do_preview))
        p.arm.on_click(lambda _: self.run(self.do_arm))
        p.execute.on_click(lambda _: self.run(self.do_execute))
        for option in (p.mode, p.dwell, p.closed_loop, p.normals):
            option.on_update(lambda _: self.arming.drop("an option changed"))
        p.scrub.on_update(lambda _: self.on_scrub())
        p.live.on_click(lambda _: self.c.follow_live())
        return self

    def _selected(self) -> int:
        return int(self.panel.selected.value)

    def message(self, text: str) -> None:
        self.panel.result.content = text

    def run(self, fn: Any) -> None:
        """Run an action (logged: the operator's presses are an audit trail); user mistakes
        and error replies become the result text."""
        event(log, "pressed", action=fn.__name__.removeprefix("do_"))
        try:
            fn()
        except (BeamrelayError, BusyError) as exc:
            self.message(f"**{exc}**")

    # picking ------------------------------------------------------------------------------
    def on_click(self, ray_origin: Any, ray_direction: Any) -> None:
        """A click on the cloud at the ray (world, m): the nearest cloud point along it, with
        its fitted surface normal, joins this session's list (and is previewed)."""
        t0 = time.perf_counter()
        cloud = self.c.cloud
        if cloud is None:
            self.message("no point cloud yet: nothing to pick")
            return
        try:
            pick = pick_point(cloud.points, ray_origin, ray_direction)
        except InputError as exc:
            self.message(f"**{exc}**")
            return
        if pick is None:
            self.message("the click hit no cloud point")
            return
        p, normal = pick.p, None
        try:
            fit = surface_normal(cloud.points, pick.p, np.asarray(ray_origin))
            p, normal = fit.project(pick.p), fit.normal
        except InputError as exc:  # a lone point: keep it without a normal
            self.message(f"{exc}; target added without a normal")
        self.edit_list(lambda t: t.add(p, normal))
        self.latency["pick"] = time.perf_counter() - t0
        if self.panel.auto_preview.value:
            self._clicked_at = t0
            self.auto_preview()

    def auto_preview(self) -> None:
        """Preview the current list; clicks during a running preview coalesce into one more
        preview after it (of the list as it is then), so the last click is always shown."""
        self._preview_wanted.set()
        while self._previewing.acquire(blocking=False):
            try:
                while self._preview_wanted.is_set():
                    self._preview_wanted.clear()
                    self.run(self.do_preview)
                self.latency["click_to_preview"] = time.perf_counter() - self._clicked_at
                self.show_stats()
            finally:
                self._previewing.release()
            if not self._preview_wanted.is_set():
                return  # else a click came in after the loop: serve it

    def edit_list(self, edit: Any) -> None:
        self.arming.drop("the target list changed")
        with self._edit:
            try:
                self.targets = edit(self.targets)
            except InputError as exc:
                self.message(f"**{exc}**")
                return
        self.draw_targets()

    def draw_targets(self) -> None:
        """The list in the panel and the markers (and path) in this browser's scene."""
        items = self.targets.items
        lines = [f"`{t.label(k)}`" + ("" if t.n is None else f" n=({t.n[0]:.2f}, {t.n[1]:.2f}, "
                 f"{t.n[2]:.2f})") for k, t in enumerate(items)]  # fmt: skip
        self.panel.targets.content = "  \n".join(lines) or "no targets: click the cloud to add one"
        self.scene.remove_by_name("/targets")
        for k, t in enumerate(items):
            self.scene.add_icosphere(f"/targets/{k}", radius=0.004, color=TARGET_COLOUR,
                                     position=t.p)  # fmt: skip
            self.scene.add_label(f"/targets/{k}/label", f"#{k}")
        mode = Mode(self.panel.mode.value)
        if mode is not Mode.POINTS and len(items) >= 2:
            try:
                P, _ = path_points(self.targets, mode)
            except (ValueError, InputError) as exc:  # a degenerate click path: said, not drawn
                self.message(f"**path: {getattr(exc, 'reason', exc)}**")
                return
            set_lines(self.scene, "/targets/path", [P], TARGET_COLOUR, 3.0)

    # plan, execute, stop ------------------------------------------------------------------
    def request(self, execute: bool) -> dict[str, Any]:
        p = self.panel
        cam = self.c.system.camera  # picks on a fixed camera's cloud go in its frame
        camera_T_world = None if cam is None or cam.robot is not None else inv_T(cam.world_T_camera)
        return build_request(self.targets, Mode(p.mode.value), execute=execute,
                             closed_loop=bool(p.closed_loop.value), dwell=float(p.dwell.value),
                             use_normals=bool(p.normals.value), camera_T_world=camera_T_world)  # fmt: skip

    def do_preview(self) -> None:
        req = self.request(execute=False)
        self.message("planning...")
        self.show_answer(self.c.operator.preview(req), executed=False)

    def do_arm(self) -> None:
        """Preview the list and arm Execute for exactly it (see :mod:`~planner.console.arming`)."""
        req = self.request(execute=False)
        self.message("arming: planning...")
        answer = self.c.operator.preview(req)
        self.show_answer(answer, executed=False)
        if self.preview is None or self.preview.n_ok == 0:
            self.message(f"**not armed: no target solved**  \n{self.panel.result.content}")
            return
        armed = self.arming.arm(req, treatment(answer.plan, self.c.laser_power), self.c.faults())
        if isinstance(armed, str):
            self.message(f"**not armed: {armed}**  \n{self.panel.result.content}")
            return
        self.message(f"**ARMED for {self.arming.window:.0f} s**: Execute runs {armed.summary}; "
                     f"an edit, a fault or STOP disarms  \n{self.panel.result.content}")  # fmt: skip

    def do_execute(self) -> None:
        req = self.request(execute=True)
        refused = self.arming.fire(req)
        if refused is not None:
            self.message(f"**{refused}**")
            return
        self.message("executing... (STOP brakes every robot)")
        self.c.follow_live()
        self.show_answer(self.c.operator.execute(req), executed=True)

    def do_stop(self) -> None:
        self.c.stop_all()
        event(log, "pressed", logging.WARNING, action="stop")
        self.message("**STOP sent**: every robot brakes, laser off")

    def show_answer(self, answer: Answer, executed: bool) -> None:
        self.answer = answer
        self.preview = preview_of(answer.plan, self.c.system, self.c.scene)
        self.draw_preview(self.preview)
        if answer.sweep is not None and len(answer.sweep.marked):
            self.scene.add_point_cloud("/preview/marked", answer.sweep.marked,
                                       colors=SPOT_COLOUR, point_size=0.003)  # fmt: skip
        self.waiting = {r: str(answer.plan.id) for r in answer.plan.execution_unanswered or ()}
        faults = self.c.robot_faults() if executed else {}
        self.message(answer_markdown(answer, self.preview, executed,
                                     tuple(f"{r}: {f}" for r, f in sorted(faults.items()))))  # fmt: skip
        duration = self.preview.duration
        self.panel.scrub.max = max(duration, 0.01)
        self.panel.scrub.disabled = duration <= 0
        self.latency["plan_round_trip"] = answer.seconds

    def draw_preview(self, pv: Preview) -> None:
        self.scene.remove_by_name("/preview")
        set_lines(self.scene, "/preview/beams", list(pv.beams), PLANNED_BEAM_COLOUR, 1.5)
        set_lines(self.scene, "/preview/sweep", [pv.sweep], SWEEP_COLOUR, 3.0)
        for f in pv.failed:
            self.scene.add_icosphere(f"/preview/failed/{f.target}", radius=0.005,
                                     color=FAILED_COLOUR, position=f.p)  # fmt: skip
            self.scene.add_label(f"/preview/failed/{f.target}/label", f"#{f.target} {f.reason}")

    def on_scrub(self) -> None:
        """The robots and beam at the scrubber's time of this session's planned trajectory."""
        traj = None if self.answer is None else self.answer.plan.trajectory
        if traj is None or not len(traj.t):
            return
        self.c.scrubbing = True
        q = joints_at(traj, self.c.system.robot_names,
                      float(self.panel.scrub.value))  # fmt: skip
        self.c.pose(q)

    # the health panel's tick --------------------------------------------------------------
    def watch_arming(self) -> None:
        """Drop the arming on a new fault or when its window ran out, and say so."""
        if self.arming.armed is None:
            return
        self.arming.watch(self.c.faults())
        if self.arming.remaining() <= 0:
            self.message(f"**disarmed**: {self.arming.dropped}  \n{self.panel.result.content}")

    def watch_verdicts(self) -> None:
        """Say what a robot the reply was waiting for answered, once its status carries the
        verdict on that request."""
        status = self.c.live.snapshot()["status"]
        for robot, request_id in list(self.waiting.items()):
            st = status.get(robot)
            ack = None if st is None else st.value.trajectory
            if ack is not None and ack.id == request_id:
                del self.waiting[robot]
                self.message(f"{self.panel.result.content}  \n{late_verdict_line(robot, ack)}")

    def arming_text(self) -> str:
        left = self.arming.remaining()
        if left > 0:
            return f"arming: **ARMED**, Execute within {left:.0f} s"
        why = f" ({self.arming.dropped})" if self.arming.dropped else ""
        return f"arming: not armed{why}"

    def show_stats(self) -> None:
        lat = " · ".join(f"{k} {1e3 * v:.0f} ms" for k, v in self.latency.items())
        self.panel.stats.content = f"cloud frames sent: {self.c.cloud_frames}  \n{lat}"
