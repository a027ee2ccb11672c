"""A slow reader's memory is returned: RSS goes back to within 10 % of its
baseline after thousands of slow readers are gone.

A real ``fpscan serve`` (``send_timeout_s`` 2 s), which runs itself on the C library's allocator
(``PYTHONMALLOC=malloc``, ``fpscan.clients.cli.serve.use_malloc``; checked in its environment): Python's own small-object allocator keeps every 1-MiB arena that
one long-lived object still occupies, so after a burst of 5000 connections its RSS stays
about 60 MB over the baseline with the same live objects (``docs/performance.md``);
with the C allocator, the server's own return of memory after a burst and its tail
(``fpscan.service.api.connections.return_memory``: a full collection and ``malloc_trim``) gives the
pages back.

5000 slow readers (``SO_RCVBUF`` 1024, 4 pipelined ``GET /openapi.json``, never read; 50
from each of 100 loopback addresses, inside the strangers' budget) are dropped by the
server at their send deadline. Once the server holds none of them (its own table of
connections), its RSS must come back within 10 % of the baseline within 10 s (``serial``:
that bound).
"""
from __future__ import annotations

import selectors
import socket
import time

import psutil
import pytest

from tests.service.service_servers import Server
from tests.service.test_strangers import _loopback_alias_works
from tests.waits import HANG_S

READERS, PER_ADDRESS = 5000, 50
SEND_S = 2.0
WITHIN = 1.10
SETTLE_S = 10.0
REQUEST = b"GET /openapi.json HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 4

pytestmark = [pytest.mark.serial,
              pytest.mark.skipif(not _loopback_alias_works(), reason="needs 127.0.0.2 (loopback /8)"),
              pytest.mark.skipif(not psutil.LINUX, reason="RSS and malloc_trim as on Linux (glibc)")]


def _held(proc: psutil.Process) -> int:
    return sum(1 for c in proc.net_connections(kind="tcp") if c.raddr and c.status == psutil.CONN_ESTABLISHED)


@pytest.mark.timeout(600)
def test_rss_returns_within_10_percent_after_5000_slow_readers(tmp_path):
    srv = Server(tmp_path / "data", env={"FPSCAN_SEND_TIMEOUT_S": str(SEND_S)}).start()
    socks: list[socket.socket] = []
    try:
        proc = psutil.Process(srv.service.pid)
        # fpscan serve restarted itself on the C allocator (fpscan.clients.cli.serve.use_malloc): its exec's environment
        assert proc.environ().get("PYTHONMALLOC") == "malloc", proc.environ().get("PYTHONMALLOC")
        with srv.client() as c:  # warm: the schema built, every route's first call made
            for _ in range(20):
                for path in ("/api/health", "/openapi.json", "/api/jobs"):
                    assert c.get(path).status_code == 200
        baseline = proc.memory_info().rss
        peak = baseline
        for i in range(READERS):
            s = socket.socket()
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
            s.bind((f"127.2.{i // PER_ADDRESS // 250}.{1 + i // PER_ADDRESS % 250}", 0))
            s.setblocking(False)
            s.connect_ex(("127.0.0.1", srv.port))
            socks.append(s)
        sent = 0
        with selectors.DefaultSelector() as sel:  # each sends once connected: four requests fit its buffer
            for s in socks:
                sel.register(s, selectors.EVENT_WRITE)
            deadline = time.monotonic() + HANG_S
            while sel.get_map():
                assert time.monotonic() < deadline, f"{len(sel.get_map())} readers never connected"
                for key, _ in sel.select(timeout=1.0):
                    sel.unregister(key.fileobj)
                    try:
                        sent += key.fileobj.send(REQUEST) == len(REQUEST)  # type: ignore[union-attr]
                    except OSError:
                        pass
        deadline = time.monotonic() + HANG_S
        while _held(proc):  # each is dropped at its send deadline
            peak = max(peak, proc.memory_info().rss)
            assert time.monotonic() < deadline, f"the server still holds {_held(proc)} readers"
            time.sleep(0.2)
        for s in socks:
            s.close()
        socks.clear()
        with srv.client() as c:
            assert c.get("/api/health").status_code == 200
        gone = time.monotonic()
        while (rss := proc.memory_info().rss) > baseline * WITHIN and time.monotonic() - gone < SETTLE_S:
            time.sleep(0.2)
        mb = 2**20
        print(f"RSS: baseline {baseline / mb:.1f} MB, peak {peak / mb:.1f} MB with {READERS} slow readers "
              f"({sent} sent their requests), {rss / mb:.1f} MB ({rss / baseline:.3f}x) "
              f"{time.monotonic() - gone:.1f} s after the last was gone")
        assert sent == READERS, sent
        assert rss <= baseline * WITHIN, (baseline, rss)
        assert peak > baseline * 1.2  # the readers did cost memory (else this proves nothing)
    finally:
        for s in socks:
            s.close()
        srv.stop()
