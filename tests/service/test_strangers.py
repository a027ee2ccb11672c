"""Strangers hold nothing: a real ``fpscan serve`` whose process may open only
1024 files (``RLIMIT_NOFILE``, set in the child before it starts), as a lab PC's default.

- 1000 sockets from one address (127.0.0.2) that connect and send nothing, or half a request
  head, hold at most ``connections_per_address`` of the server's file handles, and the
  probation pool's (taken beyond the strangers' budget for one head with the token, closed
  after ``PROBATION_HEAD_S``) for a second; the rest are refused at accept time with 503; a
  token holder's requests from another address (127.0.0.1) meanwhile all succeed; every
  socket the server took is closed once its head is late.
- Strangers holding their whole budget (per address, from the token holder's own address,
  and in all) while more keep knocking: a token holder from that same address gets every
  answer, each within 1 s (``serial``: the time bound).
- 1000 refused requests with a 60 kB path (431 before the app: the head is over
  ``max_head_bytes``) and 1000 with an 8 kB path (401 at the gate, no token) add less than
  1 MB to the server's log: refusals are logged one line per address per interval, each
  field capped.

Waits are for events (a socket closed, an answer read), never for a clock.
"""
from __future__ import annotations

import os
import socket
import sys
import time
from pathlib import Path

import httpx
import pytest

from fpscan.clients.processes import Service, clean_env, free_port
from fpscan.service.api.connections import FD_HEADROOM, ConnectionGuard
from tests.service.service_servers import TOKEN, Server
from tests.waits import HANG_S

FILES = 1024
STRANGERS = 1000
PER_ADDRESS = 64
#: connections the server takes on probation beyond the strangers' budget (its default rule)
PROBATION = ConnectionGuard(PER_ADDRESS, FILES // 2, hard_limit=FILES - FD_HEADROOM).probation_limit


def _serve_with_file_limit(data_dir: Path, log_path: Path, env: dict) -> Service:
    """``fpscan serve`` on 127.0.0.1 in a child whose open-file limit is ``FILES``."""
    port = free_port()
    boot = ("import resource, runpy, sys; "
            f"resource.setrlimit(resource.RLIMIT_NOFILE, ({FILES}, {FILES})); "
            f"sys.argv = ['fpscan', 'serve', '--host', '127.0.0.1', '--port', '{port}', '--no-web']; "
            "runpy.run_module('fpscan', run_name='__main__', alter_sys=True)")
    full_env = clean_env(FPSCAN_DATA_DIR=str(data_dir), FPSCAN_TOKEN=TOKEN, PYTHONUNBUFFERED="1",
                         FPSCAN_WARM_UP="false", FPSCAN_ALLOW_WEAK_TOKEN="true", OMP_NUM_THREADS="1", **env)
    srv = Service([sys.executable, "-c", boot], port=port, token=TOKEN, data_dir=data_dir, log_path=log_path,
                  env=full_env, cwd=Path(__file__).resolve().parents[2])
    try:
        srv.wait_healthy(HANG_S)
    except BaseException:
        srv.stop()
        raise
    return srv


def _open_files(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def _loopback_alias_works() -> bool:
    try:
        with socket.socket() as s:
            s.bind(("127.0.0.2", 0))
        return True
    except OSError:
        return False


pytestmark = [pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc to count open files"),
              pytest.mark.skipif(not _loopback_alias_works(), reason="needs 127.0.0.2 (loopback /8)")]


@pytest.fixture(scope="module")
def limited_server(tmp_path_factory):
    base = tmp_path_factory.mktemp("strangers")
    srv = _serve_with_file_limit(base / "data", base / "server.log",
                                 {"FPSCAN_HEADER_TIMEOUT_S": "2", "FPSCAN_CONNECTIONS_PER_ADDRESS": str(PER_ADDRESS)})
    yield srv
    srv.stop()


@pytest.mark.timeout(600)
def test_idle_strangers_hold_no_handles_a_token_holder_needs(limited_server):
    srv = limited_server
    assert int(open(f"/proc/{srv.pid}/limits").read().split("Max open files")[1].split()[0]) == FILES
    before = peak = _open_files(srv.pid)
    strangers: list[socket.socket] = []
    try:
        for i in range(STRANGERS):
            if i % 50 == 0:
                peak = max(peak, _open_files(srv.pid))
            s = socket.socket()
            s.bind(("127.0.0.2", 0))
            s.settimeout(HANG_S)
            s.connect(("127.0.0.1", srv.port))
            if i % 2:  # half a request head, never finished
                s.sendall(b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            strangers.append(s)
        # every stranger is answered: refused at accept (503, closed) or, for the ones the
        # server took, closed once their head is late; meanwhile a token holder is served
        with httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=HANG_S) as c:
            statuses = [c.get("/api/health").status_code for _ in range(20)]
            statuses += [c.post("/api/plans", json={"kind": "full", "lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4}})
                         .status_code for _ in range(5)]
        peak = max(peak, _open_files(srv.pid))
        answers = []
        for s in strangers:
            chunks = []
            try:
                while chunk := s.recv(65536):
                    chunks.append(chunk)
            except ConnectionResetError:
                pass
            answers.append(b"".join(chunks))
        refused = sum(1 for a in answers if a.startswith(b"HTTP/1.1 503"))
        closed = sum(1 for a in answers if a == b"")
        print(f"strangers: {STRANGERS} sockets from 127.0.0.2 under a {FILES}-file limit: {refused} refused at accept "
              f"(503), {closed} closed for a late head; server files {before} before, at most {peak} meanwhile; "
              f"token holder: {statuses.count(200)} x 200, {statuses.count(201)} x 201 of {len(statuses)}")
        assert all(st in (200, 201) for st in statuses), statuses
        assert peak <= before + PER_ADDRESS + PROBATION + 16, (before, peak)
        assert refused >= STRANGERS - PER_ADDRESS - PROBATION - 16 and refused + closed == STRANGERS, (refused, closed)
        assert all(b"too many" in a or b"holds" in a for a in answers if a.startswith(b"HTTP/1.1 503"))
    finally:
        for s in strangers:
            s.close()


@pytest.mark.timeout(600)
def test_refused_requests_with_long_paths_add_little_log(limited_server):
    srv = limited_server
    size0 = srv.log_path.stat().st_size
    long_path = "/api/" + "a" * 60_000
    medium_path = "/api/" + "b" * 8_000
    codes: dict[int, int] = {}
    for path in [long_path] * STRANGERS + [medium_path] * STRANGERS:
        with socket.create_connection(("127.0.0.1", srv.port), timeout=HANG_S, source_address=("127.0.0.3", 0)) as s:
            s.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode())
            reply = b""
            try:
                while chunk := s.recv(65536):
                    reply += chunk
            except ConnectionResetError:
                pass
        code = int(reply.split()[1]) if reply.startswith(b"HTTP/") else -1
        codes[code] = codes.get(code, 0) + 1
    # the last refusal's line (if any) is written by now: the server logs before it answers
    grew = srv.log_path.stat().st_size - size0
    print(f"log: {2 * STRANGERS} refused requests ({STRANGERS} with 60 kB paths, {STRANGERS} with 8 kB) added "
          f"{grew} bytes of log; answers {codes}")
    assert codes == {431: STRANGERS, 401: STRANGERS}, codes
    assert grew < 1_000_000, grew


def test_the_guard_s_rule():
    """Per address at most ``per_address``; beyond ``max_connections`` in all only an
    address's allowance; never beyond the hard limit; a release makes room again."""
    from fpscan.service.api.connections import ConnectionGuard

    guard = ConnectionGuard(per_address=3, max_connections=5, allowance=1, hard_limit=7, probation_limit=1)
    answers = [guard.admit("a") for _ in range(4)]
    assert answers[:3] == [None] * 3 and "holds 3 connections" in (answers[3] or "")
    assert guard.held("a") == 3 and guard.total == 3
    assert guard.admit("b") is None and guard.admit("b") is None  # 5 in all now
    assert "at most 5 beyond 1 per address" in (guard.admit("b") or "")  # b holds its allowance already
    assert guard.admit("c") is None and guard.admit("d") is None  # newcomers get their allowance: 7
    assert "as many as it can" in (guard.admit("e") or "")  # the hard limit
    guard.release("a")
    assert guard.admit("e") is None and guard.total == 7
    assert guard.refused_count == 3
    # the token: a trusted connection leaves the strangers' numbers, and only the hard limit bounds it
    guard.trust("a", "stranger")
    assert guard.held("a") == 1 and guard.strangers == 6 and guard.trusted == 1 and guard.total == 7
    guard.release("e")
    guard.release("d")
    assert guard.admit_on_probation() is None and guard.on_probation == 1  # beyond the budget: one head's time
    assert "wait to show the token" in (guard.admit_on_probation() or "")  # the probation pool is full
    guard.trust("?", "probation")
    assert guard.on_probation == 0 and guard.trusted == 2 and guard.total == 6
    assert guard.admit_on_probation() is None
    assert "as many as it can" in (guard.admit_on_probation() or "")  # the hard limit
    guard.release("a", "trusted")
    assert guard.trusted == 1 and guard.total == 6 and guard.on_probation == 1


def test_refusals_are_one_line_per_address_per_interval_with_a_count(caplog):
    import logging

    from fpscan.service.api.logcaps import CappedRecords, RefusalLog, shown

    log = logging.getLogger("fpscan.test-refusals")
    refusals = RefusalLog(log, interval_s=3600)
    with caplog.at_level(logging.INFO, logger="fpscan.test-refusals"):
        written = [refusals.refused("10.0.0.1", "refused path=%s", shown("/" + "x" * 60_000)) for _ in range(1000)]
        refusals.refused("10.0.0.2", "refused path=%s", "/api/jobs")
    assert written.count(True) == 1
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and all(len(line) < 400 for line in lines), lines
    assert "(60001 characters)" in lines[0]
    refusals.interval_s = 0.0
    with caplog.at_level(logging.INFO, logger="fpscan.test-refusals"):
        refusals.refused("10.0.0.1", "refused again")
    assert "999 more refusals from 10.0.0.1" in caplog.records[-1].getMessage()
    record = logging.LogRecord("x", logging.ERROR, __file__, 1, "%s", ("y" * 10_000,), None)
    assert CappedRecords(limit=2000).filter(record) and len(record.getMessage()) < 2100
    # a traceback counts against the same cap: 300 frames and a 30 kB message, one record
    def deep(n: int) -> None:
        if n == 0:
            raise RuntimeError("z" * 30_000)
        deep(n - 1)

    try:
        deep(300)
    except RuntimeError:
        record = logging.LogRecord("x", logging.ERROR, __file__, 1, "internal error ref=%s", ("ab12",), sys.exc_info())
    whole = len(logging.Formatter().format(logging.makeLogRecord(record.__dict__)))
    assert CappedRecords(limit=2000).filter(record) and record.exc_info is None
    written = logging.Formatter().format(record)
    assert whole > 30_000 and len(written) < 2100, (whole, len(written))
    assert written.startswith("internal error ref=ab12\nTraceback") and "characters)" in written


def _partial_head(port: int, source: str) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=HANG_S, source_address=(source, 0))
    s.sendall(b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
    return s


def _answer(s: socket.socket) -> bytes:
    chunks = []
    try:
        while chunk := s.recv(65536):
            chunks.append(chunk)
    except (ConnectionResetError, TimeoutError):
        pass
    return b"".join(chunks)


@pytest.mark.serial
@pytest.mark.timeout(600)
def test_a_token_holder_gets_in_while_strangers_hold_their_whole_budget(tmp_path):
    per_address, budget, requests = 8, 20, 30
    srv = Server(tmp_path / "data", env={"FPSCAN_CONNECTIONS_PER_ADDRESS": str(per_address),
                                         "FPSCAN_MAX_CONNECTIONS": str(budget),
                                         "FPSCAN_HEADER_TIMEOUT_S": "120"}).start()
    strangers: list[socket.socket] = []
    try:
        # the strangers' whole budget: the token holder's own address full, then others to the total
        for source in ["127.0.0.1"] * per_address + ["127.0.0.2"] * per_address + ["127.0.0.3"] * (budget - 2 * per_address):
            strangers.append(_partial_head(srv.port, source))
        with socket.create_connection(("127.0.0.1", srv.port), timeout=HANG_S) as knock:  # one more, no token
            knock.sendall(b"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            refused = _answer(knock)
        assert refused.startswith(b"HTTP/1.1 503") and b"without the token" in refused, refused
        seconds, statuses = [], []
        with srv.client(timeout=HANG_S) as kept:  # a kept-alive client, and a new connection each time
            for k in range(requests):
                t0 = time.perf_counter()
                if k % 2:
                    statuses.append(kept.get("/api/jobs").status_code)
                else:
                    with srv.client(timeout=HANG_S) as fresh:
                        statuses.append(fresh.get("/api/health").status_code)
                seconds.append(time.perf_counter() - t0)
                # strangers keep knocking from the same address meanwhile: each refused at its head
                with socket.create_connection(("127.0.0.1", srv.port), timeout=HANG_S) as knock:
                    knock.sendall(b"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                    assert _answer(knock).startswith(b"HTTP/1.1 503")
        print(f"token holder from 127.0.0.1 beside {budget} strangers' connections ({per_address} of them from "
              f"127.0.0.1, the whole budget): {statuses.count(200)} x 200 of {requests}, slowest "
              f"{max(seconds) * 1e3:.0f} ms, median {sorted(seconds)[len(seconds) // 2] * 1e3:.0f} ms")
        assert statuses == [200] * requests, statuses
        assert max(seconds) <= 1.0, seconds
    finally:
        for s in strangers:
            s.close()
        srv.stop()
