"""Slow uploads lock out no one: ten uploads from one address (127.0.0.2) that
trickle their bodies in at 20 KiB/s, under the server's floor of 100 KiB/s averaged over
``FPSCAN_BODY_RATE_WINDOW_S`` (2 s here, 10 s by default), are cut off with 408 (those the
server took) or refused at once with 429 (beyond that address's share: slots go per client
first); fifteen valid uploads from another address (127.0.0.1) meanwhile all get 201, none
429. A real ``fpscan serve``; every wait is for an answer, never for a clock."""
from __future__ import annotations

import io
import socket
import threading
import time

import numpy as np
import pytest

from tests.service.service_servers import Server
from tests.waits import HANG_S

TRICKLERS = 10
VALID = 15
TRICKLE = 20 * 1024  # bytes a second


def _loopback_alias_works() -> bool:
    try:
        with socket.socket() as s:
            s.bind(("127.0.0.2", 0))
        return True
    except OSError:
        return False


pytestmark = pytest.mark.skipif(not _loopback_alias_works(), reason="needs 127.0.0.2 (loopback /8)")


def _npy(seed: int) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(seed).standard_normal((32, 6, 6)).astype(np.float32))
    return buf.getvalue()


def _trickle(port: int, token: str, answers: list, started: threading.Barrier) -> None:
    """An upload whose body comes at ``TRICKLE`` bytes a second until the server answers."""
    head = (f"POST /api/datasets HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\n"
            "Content-Type: multipart/form-data; boundary=zzz\r\nContent-Length: 10000000\r\n\r\n"
            "--zzz\r\nContent-Disposition: form-data; name=\"file\"; filename=\"x.npy\"\r\n\r\n").encode()
    with socket.create_connection(("127.0.0.1", port), timeout=HANG_S, source_address=("127.0.0.2", 0)) as s:
        s.sendall(head)
        started.wait()
        s.settimeout(1.0 / 4)
        reply = b""
        deadline = time.monotonic() + HANG_S
        while time.monotonic() < deadline and not _complete(reply):
            try:
                chunk = s.recv(65536)
                if not chunk:
                    break
                reply += chunk
                continue
            except TimeoutError:
                pass
            except (ConnectionResetError, BrokenPipeError):
                break
            try:
                s.sendall(b"\0" * (TRICKLE // 4))  # a quarter of a second's trickle
            except (ConnectionResetError, BrokenPipeError):
                pass
    answers.append(reply.decode(errors="replace"))


def _complete(reply: bytes) -> bool:
    """Whether ``reply`` holds a whole response (its head and ``Content-Length`` bytes)."""
    head, sep, body = reply.partition(b"\r\n\r\n")
    if not sep:
        return False
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(body) >= int(value)
    return False


@pytest.mark.timeout(600)
def test_trickling_uploads_are_cut_off_and_take_no_one_elses_slots(tmp_path):
    srv = Server(tmp_path / "data", env={"FPSCAN_BODY_RATE_WINDOW_S": "2", "FPSCAN_BODY_TIMEOUT_S": "30"}).start()
    try:
        answers: list[str] = []
        started = threading.Barrier(TRICKLERS + 1, timeout=HANG_S)
        tricklers = [threading.Thread(target=_trickle, args=(srv.port, srv.token, answers, started))
                     for _ in range(TRICKLERS)]
        for t in tricklers:
            t.start()
        started.wait()  # every trickler has sent its head
        statuses: list[int] = []
        refusals: list[str] = []
        lock = threading.Lock()

        def upload(seeds) -> None:
            with srv.client(timeout=HANG_S) as c:
                for seed in seeds:
                    r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                               files={"file": (f"v{seed}.npy", _npy(seed))})
                    with lock:
                        statuses.append(r.status_code)
                        if r.status_code != 201:
                            refusals.append(r.text)

        valid = [threading.Thread(target=upload, args=(range(k, VALID, 2),)) for k in range(2)]
        for t in valid:
            t.start()
        for t in valid + tricklers:
            t.join()
        codes = [int(a.split()[1]) if a.startswith("HTTP/") else -1 for a in answers]
        print(f"uploads: {TRICKLERS} trickling at {TRICKLE // 1024} KiB/s from 127.0.0.2 answered "
              f"{codes.count(408)} x 408, {codes.count(429)} x 429; {VALID} valid ones from 127.0.0.1: "
              f"{statuses.count(201)} x 201, {statuses.count(429)} x 429")
        assert statuses == [201] * VALID, (statuses, refusals)
        assert sorted(set(codes)) <= [408, 429] and codes.count(408) >= 1, answers
        assert all("slower than" in a for a in answers if a.startswith("HTTP/1.1 408")), answers
        assert all("from this client" in a for a in answers if a.startswith("HTTP/1.1 429")), answers
    finally:
        srv.stop()
