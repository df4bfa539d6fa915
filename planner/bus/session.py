"""Zenoh plumbing shared by the planner node and the drivers.

Topology without multicast: one process (the planner node, or ``beamrelay up``) *listens* on
the bus endpoint (default ``tcp/127.0.0.1:7447``), every other process *connects* to it and
keeps retrying in the background, so start order does not matter. Peers learn about each
other through gossip. ``--zenoh-config FILE`` replaces the defaults (authentication, access
control, TLS, routers; see ``scenarios/zenoh/``).
"""

from __future__ import annotations

import json
import logging
import os
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel

from planner.bus.bodies import load_json
from planner.errors import InputError
from schemas.located import validate

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ENDPOINT_ENV = "BEAMRELAY_ZENOH_ENDPOINT"
JSON = "application/json"


def urgent() -> dict[str, Any]:
    """Publisher options of the messages safety waits on (heartbeat, stop): Zenoh's
    real-time priority and no batching, so a 1 MB cloud frame queued on the same link or
    router does not delay them past the drivers' 50-100 ms deadlines."""
    import zenoh

    return {"priority": zenoh.Priority.REAL_TIME, "express": True}


def bulk() -> dict[str, Any]:
    """Publisher options of bulk data (camera clouds): below every other message."""
    import zenoh

    return {"priority": zenoh.Priority.DATA_LOW}


MAX_PAYLOAD_BYTES = 4 * 1024 * 1024

M = TypeVar("M", bound=BaseModel)


@dataclass(frozen=True)
class Keys:
    """Key expressions under a namespace prefix (default ``beamrelay``)."""

    prefix: str = "beamrelay"

    @property
    def plan(self) -> str:
        return f"{self.prefix}/plan"

    @property
    def targets(self) -> str:
        return f"{self.prefix}/targets"

    @property
    def plans(self) -> str:
        return f"{self.prefix}/plans"

    def joint_states(self, robot: str) -> str:
        return f"{self.prefix}/{robot}/joint_states"

    def trajectory(self, robot: str) -> str:
        return f"{self.prefix}/{robot}/trajectory"

    def status(self, robot: str) -> str:
        return f"{self.prefix}/{robot}/status"

    @property
    def camera_points(self) -> str:
        return f"{self.prefix}/camera/points"

    @property
    def camera_spot(self) -> str:
        return f"{self.prefix}/camera/spot"

    @property
    def heartbeat(self) -> str:
        return f"{self.prefix}/heartbeat"

    @property
    def stop(self) -> str:
        return f"{self.prefix}/stop"

    @property
    def laser(self) -> str:
        """The laser gate state (:class:`schemas.messages.LaserState`)."""
        return f"{self.prefix}/laser"

    def setpoint(self, robot: str) -> str:
        """Streamed joint setpoints (:class:`schemas.messages.Setpoint`)."""
        return f"{self.prefix}/{robot}/setpoint"

    @property
    def target_stream(self) -> str:
        """A tracker's moving target (:class:`schemas.messages.TargetStream`)."""
        return f"{self.prefix}/targets/stream"

    @property
    def calibration(self) -> str:
        """The refined calibration (:class:`schemas.messages.CalibrationMessage`)."""
        return f"{self.prefix}/calibration"

    def alive(self, node: str) -> str:
        return f"{self.prefix}/alive/{node}"

    @property
    def alive_all(self) -> str:
        return f"{self.prefix}/alive/**"


#: Zenoh link protocols; those carried over IP take ``HOST:PORT`` as their address
IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
_ENDPOINT = re.compile(r"^(?P<proto>[A-Za-z0-9-]+)/(?P<addr>[^?#]+)(?P<rest>[?#].*)?$")
_HOST_PORT = re.compile(r"^(?P<host>\[[0-9A-Fa-f:.]+\]|[^:/\[\]]+):(?P<port>[0-9]+)$")
_LOOPBACK = re.compile(r"^(127\.\d+\.\d+\.\d+|localhost|\[::1\])$")
#: config keys holding file names: relative names are taken from the config file's folder
_PATH_KEYS = (
    "transport/auth/usrpwd/dictionary_file",
    "transport/auth/pubkey/public_key_file",
    "transport/auth/pubkey/private_key_file",
    "transport/auth/pubkey/known_keys_file",
    "transport/link/tls/root_ca_certificate",
    "transport/link/tls/listen_private_key",
    "transport/link/tls/listen_certificate",
    "transport/link/tls/connect_private_key",
    "transport/link/tls/connect_certificate",
)


def default_endpoint() -> str:
    return os.environ.get(ENDPOINT_ENV, DEFAULT_ENDPOINT)


def check_endpoint(text: str, option: str = "--endpoint") -> str:
    """``text`` if it is a Zenoh endpoint ``PROTOCOL/ADDRESS`` (``tcp/127.0.0.1:7447``,
    ``tls/localhost:7447``, ``udp/[::1]:7447``, ``unixsock-stream//tmp/bus.sock``); an
    InputError naming ``option`` and what is wrong otherwise."""
    example = f"e.g. {DEFAULT_ENDPOINT}"
    m = _ENDPOINT.match(text.strip())
    if m is None:
        hint = f" (did you mean tcp/{text.strip()}?)" if _HOST_PORT.match(text.strip()) else ""
        raise InputError(f"{option} {text!r}: expected PROTOCOL/HOST:PORT, {example}{hint}")
    proto = m["proto"].lower()
    if proto not in IP_PROTOCOLS + OTHER_PROTOCOLS:
        known = ", ".join(IP_PROTOCOLS + OTHER_PROTOCOLS)
        raise InputError(f"{option} {text!r}: unknown protocol {proto!r} (known: {known})")
    if proto in IP_PROTOCOLS:
        hp = _HOST_PORT.match(m["addr"])
        if hp is None:
            raise InputError(f"{option} {text!r}: expected {proto}/HOST:PORT, {example}")
        if not 0 <= int(hp["port"]) <= 65535:
            raise InputError(f"{option} {text!r}: port {hp['port']} outside 0-65535")
    return text.strip()


def is_local_endpoint(endpoint: str) -> bool:
    """True if only this machine can reach ``endpoint``: an IP endpoint on a loopback
    address (``127.x.x.x``, ``localhost``, ``[::1]``) or a local link (Unix socket, pipe,
    serial line)."""
    m = _ENDPOINT.match(endpoint.strip())
    if m is None:
        return False
    if m["proto"].lower() not in IP_PROTOCOLS:
        return m["proto"].lower() in ("unixsock-stream", "unixpipe", "serial")
    hp = _HOST_PORT.match(m["addr"])
    return hp is not None and _LOOPBACK.match(hp["host"]) is not None


def _gossip_listener(endpoint: str) -> list[str]:
    """Where a connecting process listens so that gossip can connect peers directly: a
    random port of the hub's protocol, on loopback when the hub is on loopback."""
    m = _ENDPOINT.match(endpoint)
    hp = _HOST_PORT.match(m["addr"]) if m else None
    if m is None or hp is None:
        return []
    host = hp["host"] if _LOOPBACK.match(hp["host"]) else "[::]"
    return [f"{m['proto']}/{host}:0"]


def _zenoh_message(exc: BaseException) -> str:
    """Zenoh's error text without its Rust source locations."""
    text = re.sub(r" at /\S+?\.rs:\d+\.?", "", str(exc))
    return " ".join(text.split())


def load_config_file(config_file: Path) -> Any:
    """A user's Zenoh config file, with relative file names resolved against its folder."""
    import zenoh

    path = Path(config_file)
    if not path.is_file():
        raise InputError(f"Zenoh config file not found: {path}")
    try:
        conf = zenoh.Config.from_file(str(path))
    except Exception as exc:  # zenoh raises its own ZError
        raise InputError(f"invalid Zenoh config: {_zenoh_message(exc)}", str(path)) from None
    for key in _PATH_KEYS:
        value = json.loads(conf.get_json(key))
        if not isinstance(value, str):
            continue
        resolved = path.parent / value
        if not resolved.is_file():
            raise InputError(f"{key}: file not found: {resolved}", str(path))
        conf.insert_json5(key, json.dumps(str(resolved.resolve())))
    return conf


def file_sets_endpoints(conf: Any) -> bool:
    """True if a loaded config names its own listen or connect endpoints."""
    import zenoh

    default = zenoh.Config()
    return any(
        conf.get_json(k) != default.get_json(k) for k in ("listen/endpoints", "connect/endpoints")
    )


# long: each Zenoh setting is written out with the reason it has that value (15 lines of docstring)
def zenoh_config(
    *,
    listen: bool,
    endpoint: str | None = None,
    config_file: Path | None = None,
    connect_timeout: float | None = None,
) -> Any:
    """A Zenoh config for the process that hosts the bus (``listen``: it listens on the
    endpoint) or for any other process (it connects to the endpoint).

    Without ``config_file``: peer mode, multicast scouting off, the endpoint (default
    ``tcp/127.0.0.1:7447``); a connecting process also listens on a random loopback port so
    that gossip can link peers directly. With ``config_file``: the file replaces those
    defaults (mode, scouting, authentication, access control, TLS; relative file names in it
    are taken from its folder); the host listens on the endpoint in the file's mode (peer or
    router) and every other process connects to it as a Zenoh *client*, which accepts no
    connections: on a bus with authentication every link is then one the host accepted and
    authenticated, and the file's access list is switched off in the client (only the host
    can tell who sent what); such a client waits ``connect_timeout`` s (None: as long as it
    takes) for the host when the session opens, then reconnects by itself. A file that names its own
    listen or connect endpoints is used as it is.
    """
    import zenoh

    if endpoint is not None:
        check_endpoint(endpoint)
    if config_file is None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
    else:
        conf = load_config_file(config_file)
        if file_sets_endpoints(conf):
            if endpoint is not None:
                raise InputError(
                    f"--endpoint {endpoint} given but the config file names its own listen/"
                    "connect endpoints: remove one of them",
                    str(config_file),
                )
            return conf
    endpoint = check_endpoint(endpoint or default_endpoint(), f"${ENDPOINT_ENV}")
    if config_file is None and not is_local_endpoint(endpoint):
        raise InputError(
            f"endpoint {endpoint} is not on loopback: a bus other machines can reach needs "
            "authentication and access control, give --zenoh-config FILE (see "
            "scenarios/zenoh/README.md)"
        )
    if listen:
        if config_file is not None and json.loads(conf.get_json("mode")) == "client":
            raise InputError(
                "mode client cannot host the bus (it listens on the endpoint): use peer or "
                "router in this process's config file",
                str(config_file),
            )
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
        return conf
    if config_file is None:
        conf.insert_json5("listen/endpoints", json.dumps(_gossip_listener(endpoint)))
    else:
        conf.insert_json5("mode", '"client"')
        # a client accepts no links, and on the one it opens no user name is known: its
        # access list could only cut it off (default deny); the host enforces the file's
        conf.insert_json5("access_control/enabled", "false")
        wait_ms = -1 if connect_timeout is None else max(1, round(1e3 * connect_timeout))
        conf.insert_json5("connect/timeout_ms", str(wait_ms))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    # keep retrying in the background instead of failing when the listener is not up yet
    conf.insert_json5("connect/exit_on_failure", "false")
    return conf


def open_session(
    *,
    listen: bool,
    endpoint: str | None = None,
    config_file: Path | None = None,
    connect_timeout: float | None = None,
) -> Any:
    """Open a Zenoh session with :func:`zenoh_config`. Zenoh's refusals (a port in use, a
    protocol this build lacks, a missing TLS key, a host that refused the credentials, ...)
    become an InputError naming the endpoints."""
    import zenoh

    conf = zenoh_config(
        listen=listen, endpoint=endpoint, config_file=config_file, connect_timeout=connect_timeout
    )
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh raises its own ZError
        where = str(config_file) if config_file is not None else ""
        raise InputError(_open_failure(conf, exc), where) from None


def _open_failure(conf: Any, exc: BaseException) -> str:
    message = _zenoh_message(exc)
    listen = ", ".join(_endpoints(conf, "listen/endpoints")) or "nothing"
    connect = ", ".join(_endpoints(conf, "connect/endpoints")) or "nothing"
    what = f"cannot open the Zenoh session (listen on {listen}; connect to {connect})"
    if "Address already in use" in message or "os error 98" in message:
        return (
            f"{what}: the port is already in use (another beamrelay serve, up or driver "
            "--listen on it? choose another with --endpoint)"
        )
    return f"{what}: {message}"


def _endpoints(conf: Any, key: str) -> list[str]:
    value = json.loads(conf.get_json(key))
    if isinstance(value, dict):  # per-mode defaults
        value = value.get(json.loads(conf.get_json("mode")) or "peer", [])
    return [str(v) for v in value]


def encode(model: BaseModel | dict[str, Any]) -> bytes:
    """JSON body of a message (pydantic model or plain dict)."""
    if isinstance(model, BaseModel):
        return model.model_dump_json().encode()
    return json.dumps(model, allow_nan=False).encode()


def decode(payload: bytes, cls: type[M]) -> M:
    """Parse and validate a JSON body, whatever it holds. Errors are :class:`InputError`
    whose ``where`` is the offending key path (``points[3]``, ``body`` for the whole body),
    ready for an error reply's ``field`` (see :mod:`planner.bus.bodies`)."""

    if len(payload) > MAX_PAYLOAD_BYTES:
        raise InputError(
            f"body of {len(payload)} bytes exceeds the limit of {MAX_PAYLOAD_BYTES} bytes", "body"
        )
    data = load_json(payload)
    try:
        return validate(cls, data)
    except RecursionError:
        raise InputError("JSON nested too deeply", "body") from None
    except InputError as exc:
        if exc.where:
            raise
        raise InputError(exc.reason, "body") from None


def decode_sample(sample: Any, cls: type[M], log: logging.Logger, what: str) -> M | None:
    """A subscriber sample's body decoded as ``cls``, or None when it does not decode (then
    logged as ``bad <what>: <reason>``): what a callback that must never raise calls."""
    try:
        return decode(sample.payload.to_bytes(), cls)
    except InputError as exc:
        log.warning("bad %s: %s", what, exc)
        return None


def update_alive(alive: set[str], lock: threading.Lock, sample: Any) -> tuple[str, bool]:
    """Apply a liveliness sample of ``<prefix>/alive/<node>`` to the set ``alive`` of nodes up
    (under ``lock``): a PUT adds the node (its token appeared), a DELETE removes it.
    Returns ``(node, up)``."""
    import zenoh

    node = str(sample.key_expr).rsplit("/", 1)[-1]
    up = sample.kind == zenoh.SampleKind.PUT
    with lock:
        (alive.add if up else alive.discard)(node)
    return node, up
