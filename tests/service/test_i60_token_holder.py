"""The token holder always gets in, at a realistic size: a real ``fpscan serve``
under a lab PC's open-file limit (1024; its default budget of strangers is then 64 per
address and 512 in all) and its default settings otherwise (the head deadline raised, so
that the strangers' partial heads stay until the test lets go).

- Strangers hold their whole budget: 64 partial heads from the token holder's own address
  (127.0.0.1) and 448 from 8 other loopback addresses; meanwhile threads keep closing and
  reopening those partial heads (from 127.0.0.1 and the others) and keep knocking with
  connections that send nothing (the probation pool), and a token holder from 127.0.0.1
  gets 200 within 1 s on every request, on new connections and a kept-alive one.
- Listen-queue churn: threads open and drop connections as fast as they can from 100
  loopback addresses while a token holder asks for health: every request is answered 200
  within 1 s.

Both hold a 1-s bound, so both are ``serial``. Each prints the figures
(requests, slowest, median, the strangers' churn).
"""
from __future__ import annotations

import http.client
import multiprocessing
import random
import socket
import time

import pytest

from tests.service.service_servers import TOKEN
from tests.service.test_strangers import FILES, _loopback_alias_works, _serve_with_file_limit
from tests.waits import HANG_S

PER_ADDRESS = 64
BUDGET = FILES // 2  # the default max_connections: half the open-file limit
OTHERS = [f"127.0.0.{k}" for k in range(2, 10)]  # 8 more addresses: 448 strangers
REQUESTS = 200
BOUND_S = 1.0

pytestmark = [pytest.mark.serial,
              pytest.mark.skipif(not _loopback_alias_works(), reason="needs 127.0.0.2 (loopback /8)")]


@pytest.fixture(scope="module")
def lab_server(tmp_path_factory):
    base = tmp_path_factory.mktemp("token-holder")
    srv = _serve_with_file_limit(base / "data", base / "server.log", {"FPSCAN_HEADER_TIMEOUT_S": "120"})
    yield srv
    srv.stop()


def _partial_head(port: int, source: str) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=HANG_S, source_address=(source, 0))
    s.sendall(b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
    return s


def _token_holder(port: int, n: int) -> tuple[list[int], list[float]]:
    """``n`` requests from 127.0.0.1 with the token, alternately on a new connection
    (health) and on a kept-alive one (the job list); their statuses and seconds."""
    statuses, seconds = [], []
    auth = {"Authorization": f"Bearer {TOKEN}"}
    kept = http.client.HTTPConnection("127.0.0.1", port, timeout=HANG_S)
    try:
        for k in range(n):
            t0 = time.perf_counter()
            conn = kept if k % 2 else http.client.HTTPConnection("127.0.0.1", port, timeout=HANG_S)
            conn.request("GET", "/api/jobs" if k % 2 else "/api/health", headers=auth)
            r = conn.getresponse()
            r.read()
            seconds.append(time.perf_counter() - t0)
            statuses.append(r.status)
            if conn is not kept:
                conn.close()
    finally:
        kept.close()
    return statuses, seconds


def _figures(seconds: list[float]) -> str:
    ordered = sorted(seconds)
    return (f"median {ordered[len(ordered) // 2] * 1e3:.1f} ms, p99 {ordered[int(len(ordered) * 0.99) - 1] * 1e3:.1f} ms, "
            f"slowest {ordered[-1] * 1e3:.1f} ms")


def _strangers(port: int, ready, go, stop, counts) -> None:
    """The strangers, in a process of their own: hold the whole budget of partial heads,
    then keep reopening them (about 400 a second, from their own addresses) and knocking
    from 127.0.0.1 with connections that send nothing (about 100 a second, 32 held at a time:
    the probation pool) from ``go`` until ``stop``."""
    rng = random.Random(60)
    held = [(source, _partial_head(port, source))
            for source in ["127.0.0.1"] * PER_ADDRESS + [a for a in OTHERS for _ in range(PER_ADDRESS)][:BUDGET - PER_ADDRESS]]
    ready.set()
    go.wait(HANG_S)
    waiting: list[socket.socket] = []
    k = 0
    while not stop.wait(0.0025):  # a pace, not a wait for an event: the strangers' rate
        i = rng.randrange(len(held))
        source, s = held[i]
        s.close()
        try:
            held[i] = (source, _partial_head(port, source))
            counts[0] += 1
        except OSError:
            pass
        k += 1
        if k % 4 == 0:
            try:
                waiting.append(socket.create_connection(("127.0.0.1", port), timeout=HANG_S))
                counts[1] += 1
            except OSError:
                pass
            if len(waiting) > 32:
                waiting.pop(0).close()
    for _, s in held:
        s.close()
    for s in waiting:
        s.close()


@pytest.mark.timeout(600)
def test_a_token_holder_gets_200_within_1_s_while_strangers_hold_and_churn_their_whole_budget(lab_server):
    srv = lab_server
    mp = multiprocessing.get_context("fork")
    ready, go, stop, counts = mp.Event(), mp.Event(), mp.Event(), mp.Array("l", 2)
    strangers = mp.Process(target=_strangers, args=(srv.port, ready, go, stop, counts))
    strangers.start()
    try:
        assert ready.wait(HANG_S), "the strangers did not open their budget"
        # the budget is full: one more stranger from the token holder's address is refused
        with socket.create_connection(("127.0.0.1", srv.port), timeout=HANG_S) as s:
            s.sendall(b"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            refused = s.recv(65536)
        assert refused.startswith(b"HTTP/1.1 503"), refused
        go.set()
        while counts[0] < 100:  # the churn is under way
            time.sleep(0.01)
        statuses, seconds = _token_holder(srv.port, REQUESTS)
    finally:
        go.set()
        stop.set()
        strangers.join(HANG_S)
    print(f"token holder from 127.0.0.1 beside strangers' whole budget ({PER_ADDRESS} partial heads from 127.0.0.1, "
          f"{BUDGET - PER_ADDRESS} from {len(OTHERS)} others; meanwhile {counts[0]} reopened, "
          f"{counts[1]} idle knocks): {statuses.count(200)} x 200 of {REQUESTS}, {_figures(seconds)}")
    assert statuses == [200] * REQUESTS, statuses
    assert max(seconds) <= BOUND_S, _figures(seconds)
    assert counts[0] > 0 and counts[1] > 0


def _churn(port: int, stop, counts) -> None:
    """Connect and drop at once, round 100 loopback addresses, as fast as one process can."""
    n = 0
    while not stop.is_set():
        source = f"127.0.{1 + n % 4}.{1 + n // 4 % 25}"
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=HANG_S, source_address=(source, 0)):
                pass
        except OSError:
            pass
        n += 1
        counts[0] = n


@pytest.mark.timeout(600)
def test_health_is_answered_within_1_s_while_100_addresses_churn_connections(lab_server):
    srv = lab_server
    mp = multiprocessing.get_context("fork")
    stop, counts = mp.Event(), mp.Array("l", 1)
    churn = mp.Process(target=_churn, args=(srv.port, stop, counts))
    churn.start()
    try:
        while counts[0] < 200:  # the churn is under way
            time.sleep(0.01)
        statuses, seconds = _token_holder(srv.port, REQUESTS)
    finally:
        stop.set()
        churn.join(HANG_S)
    print(f"listen-queue churn: {counts[0]} connections opened and dropped from 100 addresses meanwhile; "
          f"token holder {statuses.count(200)} x 200 of {REQUESTS}, {_figures(seconds)}")
    assert statuses == [200] * REQUESTS, statuses
    assert max(seconds) <= BOUND_S, _figures(seconds)
