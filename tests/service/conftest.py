"""Fixtures for the service tests (helpers in ``service_servers.py``)."""
from __future__ import annotations

import pytest

from tests.service.service_servers import Server


@pytest.fixture
def server(tmp_path):
    srv = Server(tmp_path / "data").start()
    yield srv
    srv.stop()


@pytest.fixture
def api(server):
    with server.client() as c:
        yield c


@pytest.fixture(scope="module")
def shared_server(tmp_path_factory):
    """One server for a whole test module (tests that do not need a fresh database)."""
    srv = Server(tmp_path_factory.mktemp("shared") / "data").start()
    yield srv
    srv.stop()


@pytest.fixture
def shared_api(shared_server):
    with shared_server.client() as c:
        yield c
