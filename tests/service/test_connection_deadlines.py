"""Every connection has a deadline in every phase: a real ``fpscan serve``
with its deadlines shortened by settings, and the attacks that held connections before:

- **head**: half a request head, on a new connection and on a kept-alive one after a full
  request (the clock is re-armed for each request), is closed after ``header_timeout_s``;
- **body**: a complete head with ``Content-Length: 100``, its answer read, one body byte,
  then nothing: closed once the rest is late (``body_rate_window_s`` + its bytes at
  ``body_min_rate``); a route that reads the body answers such a trickle 408;
- **response**: a reader with ``SO_RCVBUF`` 1024 that pipelines ``GET /openapi.json`` and
  never reads is dropped (a reset) after ``send_timeout_s``, its bytes with it; a slow
  reader that keeps reading gets every byte;
- **idle**: a kept-alive connection with nothing to say is closed after ``keep_alive_s``;
- **logs**: 500 readers that pipeline requests and reset the connection without reading
  (with the full-size bound scaled alike: 100 KB per 2000) add at most 25 KB of log, and no
  traceback; ``test_i60_slow_read_log.py`` makes the attack at full size (2000 readers,
  30 pipelined requests each, a default server).

A socket's end is the event each test waits for (the server's own table of connections, or
the client's read), never a clock; the deadlines' lengths are checked against the time taken
only from below (nothing is cut before its deadline).
"""
from __future__ import annotations

import socket
import threading
import time

import psutil
import pytest

from tests.service.service_servers import Server
from tests.waits import HANG_S

HEAD_S, WINDOW_S, SEND_S, KEEP_S = 1.0, 1.0, 1.0, 1.0


@pytest.fixture(scope="module")
def deadline_server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("deadlines") / "data",
                 env={"FPSCAN_HEADER_TIMEOUT_S": str(HEAD_S), "FPSCAN_BODY_RATE_WINDOW_S": str(WINDOW_S),
                      "FPSCAN_BODY_TIMEOUT_S": "5", "FPSCAN_SEND_TIMEOUT_S": str(SEND_S),
                      "FPSCAN_KEEP_ALIVE_S": str(KEEP_S)}).start()
    yield srv
    srv.stop()


def _server_side(srv: Server, local_port: int) -> bool:
    """Whether the server process still holds the connection from ``local_port``."""
    return any(c.raddr and c.raddr.port == local_port
               for c in psutil.Process(srv.service.pid).net_connections(kind="tcp"))


def _wait_closed_by_server(srv: Server, sockets: list[socket.socket]) -> None:
    ports = [s.getsockname()[1] for s in sockets]
    deadline = time.monotonic() + HANG_S
    while any(_server_side(srv, p) for p in ports):
        assert time.monotonic() < deadline, "the server still holds the connections"
        time.sleep(0.05)


def _read_to_end(s: socket.socket) -> tuple[bytes, bool]:
    """Everything the server sends until it closes; and whether it ended with a reset."""
    s.settimeout(HANG_S)
    out = b""
    try:
        while chunk := s.recv(65536):
            out += chunk
    except ConnectionResetError:
        return out, True
    return out, False


def _connect(srv: Server, rcvbuf: int | None = None) -> socket.socket:
    s = socket.socket()
    if rcvbuf:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.settimeout(HANG_S)
    s.connect(("127.0.0.1", srv.port))
    return s


def _response(s: socket.socket) -> bytes:
    """One whole response with a ``Content-Length`` body."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += s.recv(65536)
    head, _, body = data.partition(b"\r\n\r\n")
    length = int(next(line.split(b":")[1] for line in head.split(b"\r\n") if line.lower().startswith(b"content-length")))
    while len(body) < length:
        body += s.recv(65536)
    return head + b"\r\n\r\n" + body


def test_partial_heads_are_closed_at_their_deadline_on_new_and_kept_alive_connections(deadline_server):
    srv = deadline_server
    t0 = time.monotonic()
    fresh = [_connect(srv) for _ in range(3)]
    for s in fresh:
        s.sendall(b"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
    kept = [_connect(srv) for _ in range(3)]
    for s in kept:  # a whole request answered, then half of the next one
        s.sendall(b"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert _response(s).startswith(b"HTTP/1.1 200")
        s.sendall(b"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
    _wait_closed_by_server(srv, fresh + kept)
    assert time.monotonic() - t0 >= HEAD_S
    assert all(_read_to_end(s)[0] == b"" for s in fresh + kept)
    for s in fresh + kept:
        s.close()


def test_one_body_byte_then_nothing_is_closed_once_the_rest_is_late(deadline_server):
    srv = deadline_server
    auth = f"Authorization: Bearer {srv.token}\r\n"
    attackers = []
    t0 = time.monotonic()
    for path, token in [("/api/auth", ""), ("/api/health", auth), ("/openapi.json", "")] * 2:
        s = _connect(srv)
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{token}Content-Length: 100\r\n\r\n".encode())
        assert _response(s).startswith(b"HTTP/1.1 200")  # answered before its body came
        s.sendall(b"x")
        attackers.append(s)
    _wait_closed_by_server(srv, attackers)
    assert time.monotonic() - t0 >= WINDOW_S
    for s in attackers:
        s.close()
    # a route that reads its body answers the trickle: 408, the reason, the connection closed
    s = _connect(srv)
    s.sendall(f"POST /api/reconstructions HTTP/1.1\r\nHost: 127.0.0.1\r\n{auth}Content-Type: application/json\r\n"
              "Content-Length: 100\r\n\r\n{".encode())
    answer, _ = _read_to_end(s)
    s.close()
    assert answer.startswith(b"HTTP/1.1 408") and b"slower than" in answer, answer


def test_a_reader_that_does_not_read_is_dropped_and_a_slow_one_that_reads_is_served(deadline_server):
    srv = deadline_server
    readers = []
    t0 = time.monotonic()
    for _ in range(4):
        s = _connect(srv, rcvbuf=1024)
        s.sendall(b"GET /openapi.json HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 30)
        readers.append(s)
    _wait_closed_by_server(srv, readers)
    assert time.monotonic() - t0 >= SEND_S
    for s in readers:
        _, reset = _read_to_end(s)
        assert reset  # dropped with a reset: the server kept none of its bytes
        s.close()
    # a small window read steadily (4 KiB at a time) gets every byte of three answers
    s = _connect(srv, rcvbuf=4096)
    s.sendall(b"GET /openapi.json HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 2
              + b"GET /openapi.json HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
    data, reset = b"", False
    try:
        while chunk := s.recv(4096):
            data += chunk
    except ConnectionResetError:
        reset = True
    s.close()
    assert not reset and data.count(b"HTTP/1.1 200") == 3 and data.rstrip().endswith(b"}"), data[-200:]


def test_an_idle_kept_alive_connection_is_closed_after_keep_alive(deadline_server):
    srv = deadline_server
    s = _connect(srv)
    s.sendall(b"GET /api/auth HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    assert _response(s).startswith(b"HTTP/1.1 200")
    t0 = time.monotonic()
    assert _read_to_end(s)[0] == b""
    assert time.monotonic() - t0 >= KEEP_S * 0.9
    s.close()


@pytest.mark.timeout(600)
def test_readers_that_reset_write_little_log(deadline_server):
    srv = deadline_server
    n, threads = 500, 4
    size0 = srv.log.stat().st_size

    def run(k: int) -> None:
        for _ in range(k):
            s = _connect(srv, rcvbuf=1024)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
            s.sendall(b"GET /openapi.json HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 5)
            s.recv(1)  # the server is answering
            s.close()  # a reset, with its answers unread

    workers = [threading.Thread(target=run, args=(n // threads,)) for _ in range(threads)]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    with srv.client() as c:  # the server is past them all: it answers, and has logged what it would
        assert c.get("/api/health").status_code == 200
    grew = srv.log.stat().st_size - size0
    text = srv.log.read_text()[size0:]
    print(f"log: {n} readers that reset with 5 pipelined answers unread added {grew} bytes of log")
    assert grew <= 25_000, text[-3000:]
    assert "Traceback" not in text and "internal error" not in text, text[-3000:]
