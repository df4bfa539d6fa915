"""The operator console: one viser server showing the live system, picking, preview, execute.

:class:`Console` is a Zenoh client of the running system (``beamrelay up``): it reads the
public topics (:class:`~planner.console.live.LiveState`) and sends TargetRequests to
``<prefix>/plan`` (:class:`~planner.console.operator.Operator`). A drawing thread pushes the
newest cloud, the robots, the live beam and the spot to the browser at up to ``DRAW_RATE``;
the GUI callbacks (viser's thread pool) edit the target list, plan, execute and stop.
Only a browser holding the launch's token gets the page (:mod:`planner.console.gate`), and
when the last browser leaves, the console sends STOP.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from planner.console.arming import HEARTBEAT, PROTECTIVE_STOP, Arming, treatment
from planner.console.cloud import MAX_POINTS, Cloud, cloud_from_sample
from planner.console.draw import BEAM_COLOUR, RobotDrawing, add_fixed, set_lines
from planner.console.gate import Gate, guarded_serve
from planner.console.health import health_markdown
from planner.console.live import LiveState
from planner.console.operator import Answer, BusyError, Operator
from planner.console.panel import build_panel
from planner.console.picking import pick_point, surface_normal
from planner.console.preview import Preview, beam_polyline, joints_at, preview_of
from planner.console.targets import Mode, TargetList, build_request, path_points
from planner.console.view import default_view
from planner.errors import BeamrelayError, InputError
from planner.model.transforms import Array, inv_T
from planner.service.events import event
from planner.service.token import new_token

log = logging.getLogger("beamrelay.console")

#: drawing loop rate (Hz)
DRAW_RATE = 30.0
#: the health panel is refreshed at this rate (Hz)
HEALTH_RATE = 2.0
#: colours outside the cloud's depth ramp (hues 50-230 deg: yellow, green, cyan, blue) and
#: apart from each other: live beam dark grey, planned beams violet, the laser-on path red
TARGET_COLOUR = (255, 140, 0)
FAILED_COLOUR = (25, 25, 25)
SWEEP_COLOUR = (255, 30, 30)
SPOT_COLOUR = (255, 0, 200)
PLANNED_BEAM_COLOUR = (170, 90, 255)
#: s of planner-heartbeat silence (as this console hears it) that refuse or drop an arming;
#: the drivers themselves brake after 0.1 s
ARM_SILENT = 1.0


class Console:
    """The page (see the module docstring). ``start`` opens the bus and the web server."""

    def __init__(self, scenario: Path, *, host: str = "127.0.0.1", port: int = 8080,
                 endpoint: str | None = None, prefix: str = "beamrelay",
                 zenoh_config: Path | None = None, max_points: int = MAX_POINTS,
                 token: str | None = None) -> None:  # fmt: skip
        from planner.io.scenario import (
            keep_out_objects,
            load_scenario,
            scene_objects,
            system_from_scenario,
        )
        from planner.model.scene import SceneModel

        scn = load_scenario(scenario)
        self.scenario = Path(scenario).resolve()
        self.name = scn.model.name
        self.system = system_from_scenario(scn)
        self.laser_power: float | None = scn.model.system.laser.power  # W, for the energy
        self.laser_gated = scn.model.system.laser.gate is not None
        self.scene_items = scene_objects(scn)
        self.keep_out = keep_out_objects(scn)
        self.scene = SceneModel(self.scene_items)
        self.host, self.port, self.max_points = host, port, max_points
        self.gate = Gate.for_address(host, port, token or new_token())
        self.unwatched_stops = 0  # stops sent because no browser was left
        self.arming = Arming()
        self.bus = {"endpoint": endpoint, "prefix": prefix, "zenoh_config": zenoh_config}
        self.targets = TargetList()
        self.cloud: Cloud | None = None
        self.preview: Preview | None = None
        self.answer: Answer | None = None
        self.scrubbing = False
        self.latency: dict[str, float] = {}
        self.cloud_frames = 0
        self._stop = threading.Event()
        self._edit = threading.Lock()
        self._preview_wanted = threading.Event()
        self._previewing = threading.Lock()
        self._clicked_at = 0.0  # perf_counter s of the last click on the cloud

    # lifecycle ----------------------------------------------------------------------------
    def start(self) -> Console:
        """Connect to the bus, serve the page, start drawing."""
        from planner.service.client import PlanClient

        self.client = PlanClient(**self.bus)  # type: ignore[arg-type]
        self.live = LiveState(self.client.keys)
        self.live.subscribe(self.client.session)
        self._token = self.client.session.liveliness().declare_token(
            self.client.keys.alive("console")
        )
        self.operator = Operator(self.client)
        self.server = self.serve()
        if self.server.get_port() != self.port:
            self.close()
            raise InputError(f"port {self.port} is in use (viser moved to another)", "--port")
        self.server.scene.set_up_direction("+z")
        # no HDRI: its decoding and filtering cost seconds in a software-rendered browser
        self.server.scene.configure_environment_map(hdri=None)
        self.server.scene.configure_default_lights(cast_shadow=False)
        self.server.scene.add_light_ambient("/ambient", intensity=1.5)  # what the HDRI lit
        view = default_view(self.system, self.scene_items)
        cam = self.server.initial_camera
        cam.position, cam.look_at, cam.up, cam.fov = view.position, view.look_at, view.up, view.fov
        add_fixed(self.server, self.system, self.scene_items, self.keep_out)
        self.robots = RobotDrawing(self.server, self.system)
        self.robots.update({r.name: r.home for r in self.system.robots})
        self.panel = build_panel(self.server)
        self._wire()
        self._wire_wizard()
        self._thread = threading.Thread(target=self._draw_loop, name="console-draw", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if getattr(self, "wizard", None) is not None:
            self.wizard.close()
        if getattr(self, "_thread", None) is not None:
            self._thread.join(timeout=2.0)
        if getattr(self, "server", None) is not None:
            self.server.stop()
        if getattr(self, "live", None) is not None:
            self.live.close()
        if getattr(self, "client", None) is not None:
            self.client.close()

    @property
    def url(self) -> str:
        """The page's address with its token: the only way in."""
        return self.gate.url(self.host, self.port)

    def serve(self) -> Any:
        """The viser server behind :attr:`gate`; when its last browser leaves, STOP."""
        import viser

        with guarded_serve(self.gate):
            server = viser.ViserServer(host=self.host, port=self.port, verbose=False)
        server.on_client_disconnect(self._on_disconnect)
        return server

    def _on_disconnect(self, _client: Any) -> None:
        """The last browser closed its page or stopped answering its pings
        (:data:`~planner.console.gate.PING_TIMEOUT`): nobody can press STOP any more, so the
        console presses it (on viser's event loop: the put does not block)."""
        if self.server.get_clients() or self._stop.is_set():
            return
        self.operator.stop("no operator console is open (the last browser left)")
        self.unwatched_stops += 1
        print("console: the last browser left: STOP sent", flush=True)

    # wiring -------------------------------------------------------------------------------
    def _wire(self) -> None:
        p = self.panel
        self.server.scene.on_click()(self._on_click)
        p.stop.on_click(lambda _: self._do_stop())
        p.up.on_click(lambda _: self._edit_list(lambda t: t.move(self._selected(), -1)))
        p.down.on_click(lambda _: self._edit_list(lambda t: t.move(self._selected(), +1)))
        p.delete.on_click(lambda _: self._edit_list(lambda t: t.delete(self._selected())))
        p.clear.on_click(lambda _: self._edit_list(lambda t: TargetList()))
        p.mode.on_update(lambda _: self._draw_targets())
        p.plan.on_click(lambda _: self._run(self._do_preview))
        p.arm.on_click(lambda _: self._run(self._do_arm))
        p.execute.on_click(lambda _: self._run(self._do_execute))
        for option in (p.mode, p.dwell, p.closed_loop, p.normals):
            option.on_update(lambda _: self.arming.drop("an option changed"))
        p.scrub.on_update(lambda _: self._on_scrub())
        p.live.on_click(lambda _: self._follow_live())

    def _wire_wizard(self) -> None:
        from planner.console.wizard import Wizard

        self.wizard = Wizard(self.server, self.scenario, self.scene_items, self.bus)

    def _selected(self) -> int:
        return int(self.panel.selected.value)

    def _message(self, text: str) -> None:
        self.panel.result.content = text

    def _run(self, fn: Any) -> None:
        """Run an action (logged: the operator's presses are an audit trail); user mistakes
        and error replies become the result text."""
        event(log, "pressed", action=fn.__name__.removeprefix("_do_"))
        try:
            fn()
        except (BeamrelayError, BusyError) as exc:
            self._message(f"**{exc}**")

    # picking ------------------------------------------------------------------------------
    def _on_click(self, event: Any) -> None:
        t0 = time.perf_counter()
        cloud = self.cloud
        if cloud is None:
            self._message("no point cloud yet: nothing to pick")
            return
        try:
            pick = pick_point(cloud.points, event.ray_origin, event.ray_direction)
        except InputError as exc:
            self._message(f"**{exc}**")
            return
        if pick is None:
            self._message("the click hit no cloud point")
            return
        p, normal = pick.p, None
        try:
            fit = surface_normal(cloud.points, pick.p, np.asarray(event.ray_origin))
            p, normal = fit.project(pick.p), fit.normal
        except InputError as exc:  # a lone point: keep it without a normal
            self._message(f"{exc}; target added without a normal")
        self._edit_list(lambda t: t.add(p, normal))
        self.latency["pick"] = time.perf_counter() - t0
        if self.panel.auto_preview.value:
            self._clicked_at = t0
            self._auto_preview()

    def _auto_preview(self) -> None:
        """Preview the current list; clicks during a running preview coalesce into one more
        preview after it (of the list as it is then), so the last click is always shown."""
        self._preview_wanted.set()
        while self._previewing.acquire(blocking=False):
            try:
                while self._preview_wanted.is_set():
                    self._preview_wanted.clear()
                    self._run(self._do_preview)
                self.latency["click_to_preview"] = time.perf_counter() - self._clicked_at
                self._show_stats()
            finally:
                self._previewing.release()
            if not self._preview_wanted.is_set():
                return  # else a click came in after the loop: serve it

    def _edit_list(self, edit: Any) -> None:
        self.arming.drop("the target list changed")
        with self._edit:
            try:
                self.targets = edit(self.targets)
            except InputError as exc:
                self._message(f"**{exc}**")
                return
        self._draw_targets()

    def _draw_targets(self) -> None:
        """The list in the panel and the markers (and path) in the scene."""
        items = self.targets.items
        lines = [f"`{t.label(k)}`" + ("" if t.n is None else f" n=({t.n[0]:.2f}, {t.n[1]:.2f}, "
                 f"{t.n[2]:.2f})") for k, t in enumerate(items)]  # fmt: skip
        self.panel.targets.content = "  \n".join(lines) or "no targets: click the cloud to add one"
        self.server.scene.remove_by_name("/targets")
        for k, t in enumerate(items):
            self.server.scene.add_icosphere(f"/targets/{k}", radius=0.004, color=TARGET_COLOUR,
                                            position=t.p)  # fmt: skip
            self.server.scene.add_label(f"/targets/{k}/label", f"#{k}")
        mode = Mode(self.panel.mode.value)
        if mode is not Mode.POINTS and len(items) >= 2:
            try:
                P, _ = path_points(self.targets, mode)
            except ValueError as exc:
                self._message(f"**path: {exc}**")
                return
            set_lines(self.server, "/targets/path", [P], TARGET_COLOUR, 3.0)

    # plan, execute, stop ------------------------------------------------------------------
    def _request(self, execute: bool) -> dict[str, Any]:
        p = self.panel
        cam = self.system.camera  # picks on a fixed camera's cloud go in its frame
        camera_T_world = None if cam is None or cam.robot is not None else inv_T(cam.world_T_camera)
        return build_request(self.targets, Mode(p.mode.value), execute=execute,
                             closed_loop=bool(p.closed_loop.value), dwell=float(p.dwell.value),
                             use_normals=bool(p.normals.value), camera_T_world=camera_T_world)  # fmt: skip

    def _do_preview(self) -> None:
        req = self._request(execute=False)
        self._message("planning...")
        answer = self.operator.preview(req)
        self._show_answer(answer, executed=False)

    def _do_arm(self) -> None:
        """Preview the list and arm Execute for exactly it (see :mod:`~planner.console.arming`)."""
        req = self._request(execute=False)
        self._message("arming: planning...")
        answer = self.operator.preview(req)
        self._show_answer(answer, executed=False)
        if self.preview is None or self.preview.n_ok == 0:
            self._message(f"**not armed: no target solved**  \n{self.panel.result.content}")
            return
        armed = self.arming.arm(req, treatment(answer.plan, self.laser_power), self.faults())
        if isinstance(armed, str):
            self._message(f"**not armed: {armed}**  \n{self.panel.result.content}")
            return
        self._message(f"**ARMED for {self.arming.window:.0f} s**: Execute runs {armed.summary}; "
                      f"an edit, a fault or STOP disarms  \n{self.panel.result.content}")  # fmt: skip

    def robot_faults(self, snap: dict[str, Any] | None = None) -> dict[str, str]:
        """robot -> its driver's fault or protective stop, of every robot reporting one."""
        status = (snap or self.live.snapshot())["status"]
        return {robot: PROTECTIVE_STOP if st.value.protective_stop else st.value.fault
                for robot, st in status.items()
                if st.value.protective_stop or st.value.fault}  # fmt: skip

    def faults(self) -> dict[str, str]:
        """What the bus says is wrong now: :meth:`robot_faults`, and ``heartbeat`` when the
        planner's has been silent for :data:`ARM_SILENT` s."""
        snap = self.live.snapshot()
        out = self.robot_faults(snap)
        hb = snap["heartbeat"]
        if hb is None or time.monotonic() - hb.at > ARM_SILENT:
            out[HEARTBEAT] = "the planner's heartbeat is silent"
        return out

    def _do_execute(self) -> None:
        req = self._request(execute=True)
        refused = self.arming.fire(req)
        if refused is not None:
            self._message(f"**{refused}**")
            return
        self._message("executing... (STOP brakes every robot)")
        self._follow_live()
        answer = self.operator.execute(req)
        self._show_answer(answer, executed=True)

    def _do_stop(self) -> None:
        self.arming.drop("STOP")
        self.operator.stop()
        event(log, "pressed", logging.WARNING, action="stop")
        self._message("**STOP sent**: every robot brakes, laser off")

    def _show_answer(self, answer: Answer, executed: bool) -> None:
        from planner.console.report import answer_markdown

        self.answer = answer
        self.preview = preview_of(answer.plan, self.system, self.scene)
        self._draw_preview(self.preview)
        if answer.sweep is not None and len(answer.sweep.marked):
            self.server.scene.add_point_cloud("/preview/marked", answer.sweep.marked,
                                              colors=SPOT_COLOUR, point_size=0.003)  # fmt: skip
        self._message(answer_markdown(answer, self.preview, executed, self._faults(executed)))
        duration = self.preview.duration
        self.panel.scrub.max = max(duration, 0.01)
        self.panel.scrub.disabled = duration <= 0
        self.latency["plan_round_trip"] = answer.seconds

    def _faults(self, executed: bool) -> tuple[str, ...]:
        """``robot: fault`` of every robot whose driver reports one (after an execution)."""
        if not executed:
            return ()
        return tuple(f"{r}: {f}" for r, f in sorted(self.robot_faults().items()))

    def _draw_preview(self, pv: Preview) -> None:
        sc = self.server.scene
        sc.remove_by_name("/preview")
        set_lines(self.server, "/preview/beams", list(pv.beams), PLANNED_BEAM_COLOUR, 1.5)
        set_lines(self.server, "/preview/sweep", [pv.sweep], SWEEP_COLOUR, 3.0)
        for f in pv.failed:
            sc.add_icosphere(f"/preview/failed/{f.target}", radius=0.005, color=FAILED_COLOUR,
                             position=f.p)  # fmt: skip
            sc.add_label(f"/preview/failed/{f.target}/label", f"#{f.target} {f.reason}")

    # scrubbing ----------------------------------------------------------------------------
    def _on_scrub(self) -> None:
        if self.answer is None or not (self.answer.plan.get("trajectory") or {}).get("t"):
            return
        self.scrubbing = True
        q = joints_at(self.answer.plan["trajectory"], self.system.robot_names,
                      float(self.panel.scrub.value))  # fmt: skip
        self._pose(q)

    def _follow_live(self) -> None:
        self.scrubbing = False

    def _pose(self, q: dict[str, Array]) -> None:
        self.robots.update(q)
        beam = beam_polyline(self.system, q, self.scene)
        set_lines(self.server, "/beam", [beam], BEAM_COLOUR, 3.0)

    # drawing loop -------------------------------------------------------------------------
    def _draw_loop(self) -> None:
        from planner.console.drawing_loop import DrawLoop

        DrawLoop(self).run(self._stop, 1.0 / DRAW_RATE, 1.0 / HEALTH_RATE)

    def watch_arming(self) -> None:
        """Drop the arming on a new fault or when its window ran out, and say so."""
        if self.arming.armed is None:
            return
        self.arming.watch(self.faults())
        if self.arming.remaining() <= 0:
            self._message(f"**disarmed**: {self.arming.dropped}  \n{self.panel.result.content}")

    def arming_text(self) -> str:
        left = self.arming.remaining()
        if left > 0:
            return f"arming: **ARMED**, Execute within {left:.0f} s"
        why = f" ({self.arming.dropped})" if self.arming.dropped else ""
        return f"arming: not armed{why}"

    def _show_stats(self) -> None:
        lat = " · ".join(f"{k} {1e3 * v:.0f} ms" for k, v in self.latency.items())
        self.panel.stats.content = f"cloud frames sent: {self.cloud_frames}  \n{lat}"

    def health_text(self) -> str:
        nodes = ("planner", *(["camera"] if self.system.camera is not None else []),
                 *self.system.robot_names)  # fmt: skip
        rates = {r: self.live.rate(f"joints/{r}") for r in self.system.robot_names}
        rates |= {"camera": self.live.rate("spot"), "heartbeat": self.live.rate("heartbeat")}
        health = health_markdown(self.live.snapshot(), rates, nodes, time.monotonic(),
                                 gated=self.laser_gated)  # fmt: skip
        return f"{health}  \n{self.arming_text()}"

    def world_T_camera(self, q: dict[str, Array] | None) -> Array:
        return self.system.world_T_camera(q)

    def new_cloud(self, payload: bytes, attachment: bytes, q: dict[str, Array] | None) -> Cloud:
        return cloud_from_sample(payload, attachment, self.world_T_camera(q), self.max_points)
