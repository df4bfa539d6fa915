"""``beamrelay up``: planner + camera driver + one robot driver per robot, supervised.

The ``up`` process is the bus hub: it listens on the endpoint, the children connect to it.
It watches every node's liveliness token and message rates (``joint_states`` per robot,
``camera/spot``) and shows them in a rich live table; crashed children are restarted
(:class:`planner.service.supervisor.Supervisor`); Ctrl-C, SIGTERM or ``duration`` stop everything.

With ``--backend ur`` the robot drivers are *not* restarted automatically: a driver of a real
arm that died stays down (the table says so) until the operator acknowledges with
``beamrelay robot recover --name <robot>``, which publishes on ``<prefix>/<robot>/recover``;
``up`` then restarts that driver. Each robot gets its own controller address (``hosts``).
"""

from __future__ import annotations

import contextlib
import signal
import sys
import tempfile
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from planner.bus.priority import raised_priority
from planner.bus.session import (
    Keys,
    default_endpoint,
    file_sets_endpoints,
    load_config_file,
    open_session,
    update_alive,
)
from planner.errors import InputError
from planner.model.scene import tracked_objects
from planner.service.online_file import check_output_file
from planner.service.supervisor import LogTail, Supervisor
from planner.service.token import TOKEN_ENV, console_url, new_token
from schemas.messages import parse_recover

RATE_WINDOW = 2.0  # s over which message rates are averaged


# long: 15 settings (18 lines) and a 10-line docstring; one command line per child process
def child_commands(
    scenario: Path,
    robots: list[str],
    *,
    backend: str = "sim",
    endpoint: str,
    prefix: str = "beamrelay",
    camera: bool = True,
    zenoh_config: Path | None = None,
    planner_zenoh_config: Path | None = None,
    hosts: dict[str, str] | None = None,
    tracker: bool = False,
    console_port: int | None = None,
    console_workdir: Path | None = None,
    online_calibration: Path | None = None,
    role_configs: dict[str, Path] | None = None,
    ros_domain: int | None = None,
) -> dict[str, list[str]]:
    """argv of every child: ``planner``, ``camera`` (if any), the simulated ``tracker`` (sim
    only, when asked: the scenario has targets on a moving object), one per robot, then the
    operator ``console`` on ``console_port`` (loopback) if given, with ``console_workdir``
    as its ``--workdir`` (the calibration wizard's files) if given. Every child gets
    ``zenoh_config`` except the planner, which gets ``planner_zenoh_config`` if given (its
    own identity on a bus with access control). ``role_configs`` (see :func:`role_files`)
    instead gives each child the file of its role: ``planner``, ``camera``, ``tracker``,
    ``driver`` (every robot), ``console``, ``ros2``. With ``ros_domain`` the ROS 2 bridge
    runs as ``ros2`` (with the ``ros2`` role: it reads the bus, publishes the ROS 2 keys and
    forwards ROS 2 targets as plan-only requests)."""
    cli = [sys.executable, "-m", "planner.cli"]
    bus = ["--endpoint", endpoint, *(["--prefix", prefix] if prefix != "beamrelay" else [])]
    planner_bus = list(bus)
    if zenoh_config is not None:
        bus += ["--zenoh-config", str(zenoh_config)]
    if (planner_conf := planner_zenoh_config or zenoh_config) is not None:
        planner_bus += ["--zenoh-config", str(planner_conf)]

    def role_bus(role: str) -> list[str]:
        if role_configs is None:
            return planner_bus if role == "planner" else bus
        return [*bus, "--zenoh-config", str(role_configs[role])]

    online = [] if online_calibration is None else ["--online-calibration", str(online_calibration)]
    out = {"planner": [*cli, "serve", str(scenario), "--connect", *role_bus("planner"), *online]}
    if camera:
        cam_backend = "sim" if backend == "sim" else "realsense"
        out["camera"] = [
            *cli, "driver", "camera", "--backend", cam_backend, "--scenario", str(scenario),
            *role_bus("camera"),
        ]  # fmt: skip
    if tracker and backend == "sim":
        out["tracker"] = [
            *cli,
            "driver",
            "tracker",
            "--scenario",
            str(scenario),
            *role_bus("tracker"),
        ]
    for r in robots:
        host = ["--host", hosts[r]] if hosts and r in hosts else []
        out[r] = [
            *cli, "driver", "robot", "--name", r, "--backend", backend, *host, "--scenario",
            str(scenario), *role_bus("driver"),
        ]  # fmt: skip
    if console_port is not None:
        out["console"] = [
            *cli,
            "console",
            str(scenario),
            "--port",
            str(console_port),
            *role_bus("console"),
        ]
        if console_workdir is not None:
            out["console"] += ["--workdir", str(console_workdir)]
    if ros_domain is not None:
        out["ros2"] = [
            *cli, "ros2", "bridge", str(scenario), "--ros-domain", str(ros_domain),
            *role_bus("ros2"),
        ]  # fmt: skip
    return out


def has_tracked_targets(scn: Any) -> bool:
    """True when some of the scenario's ``targets.points`` lie on a moving scene object."""
    if scn.model.targets.points is None or not any(o.motion for o in scn.model.scene):
        return False
    from planner.io.scenario import scene_objects, system_from_scenario, targets_from_scenario

    t = targets_from_scenario(scn, system_from_scenario(scn))
    return bool(tracked_objects(scene_objects(scn), t.points, t.normals))


def parse_hosts(items: list[str], robots: list[str], backend: str) -> dict[str, str]:
    """``NAME=ADDRESS`` items -> {robot: address}; the ur backend needs one per robot."""
    hosts: dict[str, str] = {}
    for item in items:
        name, sep, addr = item.partition("=")
        if not sep or not name or not addr or any(c.isspace() for c in item):
            raise InputError(
                f"expected NAME=ADDRESS (e.g. arm0=192.168.1.10), got {item!r}", "--host"
            )
        if name not in robots:
            raise InputError(
                f"unknown robot {name!r}; the scenario has {', '.join(robots)}", "--host"
            )
        if name in hosts:
            raise InputError(f"robot {name!r} given twice", "--host")
        hosts[name] = addr
    if backend == "ur" and (missing := [r for r in robots if r not in hosts]):
        raise InputError(
            f"the ur backend needs one controller per robot: add --host {missing[0]}=ADDRESS"
            + (f" (missing: {', '.join(missing)})" if len(missing) > 1 else ""),
            "--host",
        )
    if backend != "ur" and hosts:
        raise InputError("only the ur backend talks to controllers", "--host")
    return hosts


class Health:
    """Liveliness and message rates seen on the bus (thread safe enough for a display)."""

    def __init__(self, session: Any, keys: Keys) -> None:
        self.alive: set[str] = set()
        self.stamps: dict[str, deque[float]] = {}
        self._lock = threading.Lock()
        self._subs = [
            session.liveliness().declare_subscriber(keys.alive_all, self._on_alive, history=True),
            session.declare_subscriber(keys.joint_states("*"), self._on_joints),
            session.declare_subscriber(keys.camera_spot, self._on_spot),
            session.declare_subscriber(f"{keys.prefix}/*/recover", self._on_recover),
        ]
        self.recover_requests: list[str] = []  # robots the operator acknowledged

    def _on_alive(self, sample: Any) -> None:
        update_alive(self.alive, self._lock, sample)

    def _tick(self, name: str) -> None:
        now = time.monotonic()
        with self._lock:
            q = self.stamps.setdefault(name, deque())
            q.append(now)
            while q and now - q[0] > RATE_WINDOW:
                q.popleft()

    def _on_joints(self, sample: Any) -> None:
        self._tick(str(sample.key_expr).split("/")[-2])

    def _on_spot(self, sample: Any) -> None:
        self._tick("camera")

    def _on_recover(self, sample: Any) -> None:

        robot = str(sample.key_expr).split("/")[-2]
        try:
            parse_recover(sample.payload.to_bytes(), robot)
        except (ValueError, UnicodeDecodeError):
            return
        with self._lock:
            self.recover_requests.append(robot)

    def take_recover_requests(self) -> list[str]:
        with self._lock:
            out, self.recover_requests = self.recover_requests, []
        return out

    def rate(self, name: str) -> float:
        """Messages per second over the last ``RATE_WINDOW`` s (joint_states or spot)."""
        now = time.monotonic()
        with self._lock:
            q = self.stamps.get(name)
            return 0.0 if not q else sum(1 for t in q if now - t <= RATE_WINDOW) / RATE_WINDOW

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


def health_table(sup: Supervisor, health: Health, title: str) -> Any:
    """The rich table of children: process state, liveliness, rate, restarts."""
    from rich.table import Table

    table = Table(title=title)
    for col in ("node", "pid", "process", "alive", "rate \\[Hz]", "restarts", "uptime \\[s]"):
        table.add_column(col)
    for name, c in sup.children.items():
        if c.running:
            state = "[green]running[/]"
        elif c.proc is None:
            state = "not started"
        elif c.awaiting_operator:
            state = (
                f"[red]exited {c.proc.returncode}[/], not restarted: check the arm, then "
                f"`beamrelay robot recover --name {name}`"
            )
        else:
            state = f"[red]exited {c.proc.returncode}[/], restarting"
        alive = "[green]yes[/]" if name in health.alive else "[red]no[/]"
        rate = "" if name == "planner" else f"{health.rate(name):.0f}"
        table.add_row(
            name, str(c.pid or "-"), state, alive, rate, str(c.restarts), f"{sup.uptime(name):.0f}"
        )
    return table


def _child_config(path: Path | None) -> Path | None:
    """A Zenoh config file fit to be shared by several processes (absolute path), or None."""
    if path is None:
        return None
    if file_sets_endpoints(load_config_file(path)):
        raise InputError(
            "beamrelay up starts several processes on one bus: leave listen/connect "
            "endpoints out of the file and give the bus with --endpoint",
            str(path),
        )
    return path.resolve()


#: the role files of a folder given to ``up --zenoh-roles`` (scenarios/zenoh/roles/)
ROLES = ("planner", "driver", "camera", "tracker", "console", "ros2")


def role_files(folder: Path) -> dict[str, Path]:
    """``FOLDER/<role>.json5`` of every role in :data:`ROLES`, checked as for ``up``."""
    files = {r: Path(folder) / f"{r}.json5" for r in ROLES}
    for path in files.values():
        if not path.is_file():
            raise InputError(f"--zenoh-roles {folder}: no {path.name} in it ({', '.join(ROLES)})")
    return {r: p for r, p in ((r, _child_config(p)) for r, p in files.items()) if p is not None}


def _print_events(console: Any, tail: LogTail | None) -> None:
    """Print the lines the children logged since the last call, each after its name."""
    for name, line in tail.lines() if tail is not None else []:
        console.print(f"{name}: {line}", markup=False, highlight=False, soft_wrap=True)


# long: the supervisor's start-up and shutdown sequence, in the order the processes must start and stop
def run_up(
    scenario: Path,
    *,
    backend: str = "sim",
    duration: float | None = None,
    endpoint: str | None = None,
    prefix: str = "beamrelay",
    log_dir: Path | None = None,
    live: bool = True,
    zenoh_config: Path | None = None,
    planner_zenoh_config: Path | None = None,
    hosts: list[str] | None = None,
    console_port: int | None = None,
    console_workdir: Path | None = None,
    online_calibration: Path | None = None,
    zenoh_roles: Path | None = None,
    ros_domain: int | None = None,
) -> dict[str, int | None]:
    """Run the system until Ctrl-C / SIGTERM / ``duration`` s; the children's exit codes.
    With ``console_port`` the operator console runs as one more supervised child (its
    wizard's files in ``console_workdir``, default a per-user folder), with
    ``ros_domain`` the ROS 2 bridge (``beamrelay ros2 bridge``).

    ``zenoh_config`` is used by ``up`` itself and passed on to every child,
    ``planner_zenoh_config`` (default ``zenoh_config``) to the planner child only.
    ``zenoh_roles``, a folder of role files (:func:`role_files`), instead gives every child
    the file of its role and ``up`` itself the console's.
    """
    from rich.console import Console
    from rich.live import Live

    from planner.io.scenario import load_scenario

    scn = load_scenario(scenario)
    robots = [r.name for r in scn.model.system.robots]
    host_map = parse_hosts(hosts or [], robots, backend)
    endpoint = endpoint or default_endpoint()
    configs = [_child_config(c) for c in (zenoh_config, planner_zenoh_config)]
    roles = None
    if zenoh_roles is not None:
        if zenoh_config is not None or planner_zenoh_config is not None:
            raise InputError(
                "--zenoh-roles gives every process its file: leave out --zenoh-config and "
                "--planner-zenoh-config"
            )
        if ros_domain not in (None, 0):
            raise InputError(
                f"--ros-domain {ros_domain} with --zenoh-roles: the shipped role files allow"
                " the ROS 2 keys of domain 0 (0/**, @ros2_lv/0/**); edit their ROS 2 rules"
                " for another domain and use --zenoh-config per process"
            )
        roles = role_files(zenoh_roles)
        configs = [roles["console"], None]
    has_camera = scn.model.system.camera is not None
    online = None
    if online_calibration is not None:  # checked here: a bad FILE is exit 2, not a crash loop
        online = check_output_file(online_calibration, scenario)
    argv = child_commands(
        Path(scenario).resolve(), robots, backend=backend, endpoint=endpoint, prefix=prefix,
        camera=has_camera, zenoh_config=configs[0], planner_zenoh_config=configs[1],
        hosts=host_map, tracker=has_camera and has_tracked_targets(scn),
        console_port=console_port, console_workdir=console_workdir, online_calibration=online,
        role_configs=roles,
        ros_domain=ros_domain,
    )  # fmt: skip
    log_dir = Path(log_dir or tempfile.mkdtemp(prefix="beamrelay-up-"))
    with raised_priority() as got:  # the hub routes the heartbeat: its threads first
        session = open_session(listen=True, endpoint=endpoint, config_file=configs[0])
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    console = Console(stderr=not live)
    live = live and console.is_terminal  # without a terminal: the children's event lines
    health = Health(session, Keys(prefix))
    env, page = {}, None
    if console_port is not None:  # one token for the launch: a restarted console keeps it
        token = new_token()
        env["console"], page = {TOKEN_ENV: token}, console_url("127.0.0.1", console_port, token)
    sup = Supervisor(argv, log_dir, manual=tuple(robots) if backend == "ur" else (), env=env)
    tail = None if live else LogTail(log_dir, list(argv))
    title = f"beamrelay up {scn.model.name} on {endpoint} (logs {log_dir})"
    t_end = None if duration is None else time.monotonic() + duration
    try:
        console.log(f"bus hub {got.note}")
        sup.start()
        if page is not None:
            console.print(f"operator console: {page}", markup=False, highlight=False,
                          soft_wrap=True)  # fmt: skip
        view = Live(health_table(sup, health, title), console=console) if live else None
        with view or contextlib.nullcontext():
            while not stop.wait(0.25):
                for name in sup.poll():
                    console.log(f"restarted {name}")
                for name in health.take_recover_requests():
                    if sup.restart(name):
                        console.log(f"restarted {name} (operator recover)")
                if view is not None:
                    view.update(health_table(sup, health, title))
                _print_events(console, tail)
                if t_end is not None and time.monotonic() >= t_end:
                    break
    finally:
        codes = sup.stop(order=["planner"])
        _print_events(console, tail)
        health.close()
        session.close()
        for s, h in previous.items():
            signal.signal(s, h)
    console.print()
    console.print(f"stopped: {', '.join(f'{n}={c}' for n, c in codes.items())}")
    return codes
