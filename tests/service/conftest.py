"""Fixtures for the service tests (helpers in ``service_servers.py``)."""
from __future__ import annotations

import pytest
from service_servers import Server


@pytest.fixture
def server(tmp_path):
    srv = Server(tmp_path / "data").start()
    yield srv
    srv.stop()


@pytest.fixture
def api(server):
    with server.client() as c:
        yield c
