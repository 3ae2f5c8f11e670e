"""Fixtures shared by the service tests: each module starts its own ``server`` (its own settings), and talks to it
through this ``client``."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest

from ..service_server import ServiceServer


@pytest.fixture()
def client(server: ServiceServer) -> Iterator[httpx.Client]:
    """An HTTP client of the module's ``server`` (a module may override it, e.g. with a longer timeout)."""
    with httpx.Client(base_url=server.url, timeout=60) as c:
        yield c
