"""Zenoh plumbing shared by the planner node and the drivers (SPEC section 6).

Topology without multicast: one process (the planner node, or ``beamrelay up``) *listens* on
the bus endpoint (default ``tcp/127.0.0.1:7447``), every other process *connects* to it and
keeps retrying in the background, so start order does not matter. Peers learn about each
other through gossip. ``--zenoh-config FILE`` replaces all of this (routers, TLS, ACL).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel

from planner.errors import InputError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ENDPOINT_ENV = "BEAMRELAY_ZENOH_ENDPOINT"
JSON = "application/json"
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

    def setpoint(self, robot: str) -> str:
        return f"{self.prefix}/{robot}/setpoint"

    def alive(self, node: str) -> str:
        return f"{self.prefix}/alive/{node}"

    @property
    def alive_all(self) -> str:
        return f"{self.prefix}/alive/**"


def default_endpoint() -> str:
    return os.environ.get(ENDPOINT_ENV, DEFAULT_ENDPOINT)


def zenoh_config(
    *, listen: bool, endpoint: str | None = None, config_file: Path | None = None
) -> Any:
    """A Zenoh config: peer mode, TCP on loopback, multicast scouting off (or a user file)."""
    import zenoh

    if config_file is not None:
        if not Path(config_file).is_file():
            raise InputError(f"Zenoh config file not found: {config_file}")
        try:
            return zenoh.Config.from_file(str(config_file))
        except Exception as exc:  # zenoh raises its own ZError subclasses
            raise InputError(f"invalid Zenoh config: {exc}", str(config_file)) from exc
    endpoint = endpoint or default_endpoint()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    else:
        # a random loopback port of its own, so gossip can connect peers directly
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        # keep retrying in the background instead of failing when the listener is not up yet
        conf.insert_json5("connect/exit_on_failure", "false")
    return conf


def open_session(
    *, listen: bool, endpoint: str | None = None, config_file: Path | None = None
) -> Any:
    """Open a Zenoh session with :func:`zenoh_config`."""
    import zenoh

    return zenoh.open(zenoh_config(listen=listen, endpoint=endpoint, config_file=config_file))


def encode(model: BaseModel | dict[str, Any]) -> bytes:
    """JSON body of a message (pydantic model or plain dict)."""
    if isinstance(model, BaseModel):
        return model.model_dump_json().encode()
    return json.dumps(model, allow_nan=False).encode()


def decode(payload: bytes, cls: type[M]) -> M:
    """Parse and validate a JSON body, whatever it holds. Errors are :class:`InputError`
    whose ``where`` is the offending key path (``points[3]``, ``body`` for the whole body),
    ready for an error reply's ``field`` (see :mod:`planner.bodies`)."""
    from planner.bodies import load_json
    from schemas.located import validate

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
