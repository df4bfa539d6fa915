"""A free loopback endpoint for the bridge's bus."""

from __future__ import annotations

import pytest

from tests.drivers.conftest import free_port


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"
