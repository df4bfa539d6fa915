"""The operator console: one viser server showing the live system, picking, preview, execute.

:class:`Console` is a Zenoh client of the running system (``beamrelay up``): it reads the
public topics (:class:`~planner.console.live.LiveState`) and sends TargetRequests to
``<prefix>/plan`` (:class:`~planner.console.operator.Operator`). A drawing thread pushes the
newest cloud, the robots, the live beam and the spot to every browser at up to ``DRAW_RATE``.
Each browser gets a :class:`~planner.console.session.Session` of its own: its panel, target
list, preview and arming (viser's per-client GUI and scene); its GUI callbacks (viser's
thread pool) edit its list, plan, arm, execute and stop.
Only a browser holding the launch's token gets the page (:mod:`planner.console.gate`), and
when the last browser leaves, the console sends STOP.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

from planner.console.arming import HEARTBEAT, PROTECTIVE_STOP
from planner.console.cloud import MAX_POINTS, Cloud, cloud_from_sample
from planner.console.draw import BEAM_COLOUR, RobotDrawing, add_fixed, set_lines
from planner.console.drawing_loop import DrawLoop
from planner.console.gate import Gate, guarded_serve
from planner.console.health import health_markdown
from planner.console.live import LiveState
from planner.console.operator import Operator
from planner.console.panel import build_panel
from planner.console.preview import beam_polyline
from planner.console.session import Session
from planner.console.view import default_view
from planner.console.wizard import Wizard
from planner.errors import InputError
from planner.model.scene import SceneModel
from planner.model.transforms import Array
from planner.service.client import PlanClient
from planner.service.token import new_token

log = logging.getLogger("beamrelay.console")

#: drawing loop rate (Hz)
DRAW_RATE = 30.0
#: the health panel is refreshed at this rate (Hz)
HEALTH_RATE = 2.0
#: s of planner-heartbeat silence (as this console hears it) that refuse or drop an arming;
#: the drivers themselves brake after 0.1 s
ARM_SILENT = 1.0


class Console:
    """The page (see the module docstring). ``start`` opens the bus and the web server."""

    def __init__(self, scenario: Path, *, host: str = "127.0.0.1", port: int = 8080,
                 endpoint: str | None = None, prefix: str = "beamrelay",
                 zenoh_config: Path | None = None, max_points: int = MAX_POINTS,
                 token: str | None = None, workdir: Path | None = None) -> None:  # fmt: skip
        from planner.io.scenario import (
            keep_out_objects,
            load_scenario,
            scene_objects,
            system_from_scenario,
        )

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
        self.bus = {"endpoint": endpoint, "prefix": prefix, "zenoh_config": zenoh_config}
        self.workdir = workdir  # the wizard's files (None: the per-user default)
        self.cloud: Cloud | None = None
        self.scrubbing = False  # a session shows its planned trajectory, not the live robots
        self.cloud_frames = 0
        self.sessions: dict[int, Session] = {}  # viser client id -> its browser's session
        self._stop = threading.Event()

    # lifecycle ----------------------------------------------------------------------------
    def start(self) -> Console:
        """Connect to the bus, serve the page, start drawing."""

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
        self._wire_wizard()
        self.server.on_client_connect(self._on_connect)
        self.server.scene.on_click()(self._on_click)
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

    def _on_connect(self, client: Any) -> None:
        """A browser opened the page (with the token): its own panel and scene."""
        self.sessions[client.client_id] = Session(self, build_panel(client), client.scene).wire()

    def _on_disconnect(self, client: Any) -> None:
        """A browser left (closed its page, or stopped answering its pings for
        :data:`~planner.console.gate.PING_TIMEOUT`): its session goes. When it was the last,
        nobody can press STOP any more, so the console presses it (on viser's event loop: the
        put does not block)."""
        self.sessions.pop(client.client_id, None)
        if self.server.get_clients() or self._stop.is_set():
            return
        self.operator.stop("no operator console is open (the last browser left)")
        self.unwatched_stops += 1
        print("console: the last browser left: STOP sent", flush=True)

    # wiring -------------------------------------------------------------------------------
    def _on_click(self, event: Any) -> None:
        """A click in a browser's scene: that browser's session picks."""
        session = self.sessions.get(event.client_id)
        if session is not None:
            session.on_click(event.ray_origin, event.ray_direction)

    def _wire_wizard(self) -> None:

        self.wizard = Wizard(self.server, self.scenario, self.scene_items, self.bus, self.workdir)

    def stop_all(self, reason: str = "operator pressed Stop") -> None:
        """STOP for every robot (any session presses it for all); every arming is dropped."""
        for session in list(self.sessions.values()):
            session.arming.drop("STOP")
        self.operator.stop(reason)

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

    def follow_live(self) -> None:
        """Draw the live robots again (after a session scrubbed its planned trajectory)."""
        self.scrubbing = False

    def pose(self, q: dict[str, Array]) -> None:
        """The robots and the model beam at joints ``q`` (rad), for every browser."""
        self.robots.update(q)
        beam = beam_polyline(self.system, q, self.scene)
        set_lines(self.server.scene, "/beam", [beam], BEAM_COLOUR, 3.0)

    # drawing loop -------------------------------------------------------------------------
    def _draw_loop(self) -> None:

        DrawLoop(self).run(self._stop, 1.0 / DRAW_RATE, 1.0 / HEALTH_RATE)

    def health_text(self) -> str:
        nodes = ("planner", *(["camera"] if self.system.camera is not None else []),
                 *self.system.robot_names)  # fmt: skip
        rates = {r: self.live.rate(f"joints/{r}") for r in self.system.robot_names}
        rates |= {"camera": self.live.rate("spot"), "heartbeat": self.live.rate("heartbeat")}
        return health_markdown(self.live.snapshot(), rates, nodes, time.monotonic(),
                               gated=self.laser_gated, keep_out=len(self.keep_out))  # fmt: skip

    def world_T_camera(self, q: dict[str, Array] | None) -> Array:
        return self.system.world_T_camera(q)

    def new_cloud(self, payload: bytes, attachment: bytes, q: dict[str, Array] | None) -> Cloud:
        return cloud_from_sample(payload, attachment, self.world_T_camera(q), self.max_points)
