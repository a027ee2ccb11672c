"""Fixtures of the client tests: one ``fpscan serve`` per test module."""
from __future__ import annotations

import pytest

from tests.clients.clients_servers import fpscan_server, has_command


@pytest.fixture(scope="module")
def server(request, tmp_path_factory):
    """The URL of a real ``fpscan serve`` on loopback for the requesting module, guarded
    by that module's ``TOKEN``; skips where this build has no ``fpscan serve``."""
    if not has_command("serve"):
        pytest.skip("`fpscan serve` not available")
    data = tmp_path_factory.mktemp("srv") / "data"
    data.mkdir()
    with fpscan_server(data, token=request.module.TOKEN) as (url, _proc):
        yield url
