"""Fixtures of the planner-node tests."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack

import numpy as np
import pytest

from planner.bus.session import Keys, open_session
from planner.service.handler import RequestHandler
from planner.service.heartbeat import BusAddress
from planner.service.node import PlannerNode
from tests.drivers.conftest import free_port, wait_for
from tests.planner.raw_zenoh import raw_session
from tests.planner.service.fake_driver import PREFIX, FakeDriver, NodeRig, NodeRigFactory


@pytest.fixture
def node_rig() -> Iterator[NodeRigFactory]:
    """``node_rig(handler, q0, configure=None)``: a started :class:`PlannerNode` serving
    ``handler`` under the prefix ``PREFIX`` on a private loopback bus (heartbeat from its
    child process), a raw client session, and a :class:`FakeDriver` of ``arm0`` at joints
    ``q0`` (rad) that the node has seen; ``configure(node)`` runs before the node starts.
    Everything is closed after the test."""
    with ExitStack() as stack:

        def make(
            handler: RequestHandler,
            q0: np.ndarray,
            configure: Callable[[PlannerNode], None] | None = None,
        ) -> NodeRig:
            endpoint = f"tcp/127.0.0.1:{free_port()}"
            hub = open_session(listen=True, endpoint=endpoint)
            stack.callback(hub.close)
            node = PlannerNode(handler, hub, Keys(PREFIX), bus=BusAddress(endpoint))
            if configure is not None:
                configure(node)
            node.start()
            stack.callback(node.close)
            client, fake_side = raw_session(endpoint), raw_session(endpoint)
            stack.callback(fake_side.close)
            stack.callback(client.close)
            names = list(handler.system.robots[0].joint_names)
            fake = FakeDriver(fake_side, "arm0", names, q0)
            stack.callback(fake.close)
            wait_for(lambda: "arm0" in node.alive and node.joints.get("arm0") is not None,
                     20.0, "fake driver seen by the node")  # fmt: skip
            return node, client, fake

        yield make
