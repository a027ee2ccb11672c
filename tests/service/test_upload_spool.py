"""Uploads spool inside the data folder, counted by the disk admission: a body is spooled to
``<data_dir>/incoming`` (not the system's TMPDIR) once its length has been admitted against
the free disk (counting the uploads and imports in flight), else 507 before a byte of it is
read; a spool that fails while it is written answers 507 with the reason, and is logged
(today's main: 400 "There was an error parsing the body", nothing logged).

Oracles: a real server; the kernel's view of its open files (``/proc/PID/fd``); a real
file-size limit on the server process (``RLIMIT_FSIZE``, set with prlimit(2): a write past
it fails with EFBIG, as a full disk fails one with ENOSPC)."""
from __future__ import annotations

import http.client
import io
import os
import shutil
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from tests.service.service_servers import TOKEN, Server
from tests.waits import HANG_S

GiB = 2**30
BOUNDARY = "spool-test-boundary"


@pytest.fixture(scope="module")
def tight_server(tmp_path_factory):
    """A server whose disk admission has 4 GiB of room (the disk's free space less its
    reserve): 4 GiB give or take what other programs write meanwhile, and uploads far larger
    than anything a test sends, declared and never sent."""
    data = tmp_path_factory.mktemp("spool") / "data"
    reserve = shutil.disk_usage(data.parent).free - 4 * GiB
    if reserve <= 0:
        pytest.skip("needs more than 4 GiB free on the test folder's disk")
    spool = tmp_path_factory.mktemp("spool-tmp")  # the server's TMPDIR: nothing may be spooled there
    srv = Server(data, env={"FPSCAN_DISK_RESERVE_BYTES": str(reserve), "FPSCAN_UPLOAD_LIMIT": str(8 * GiB),
                            "FPSCAN_BODY_TIMEOUT_S": "5", "TMPDIR": str(spool)}).start()
    srv.spool = spool
    yield srv
    srv.stop()


def _begin_upload(srv: Server, length: int, first: bytes) -> http.client.HTTPConnection:
    """An upload whose head declares a body of ``length`` bytes (``Content-Length``), of
    which only the multipart start and ``first`` file bytes are sent."""
    start = (f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="format"\r\n\r\nnpy\r\n'
             f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="file"; filename="big.npy"\r\n'
             "Content-Type: application/octet-stream\r\n\r\n").encode()
    conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    conn.putrequest("POST", "/api/datasets")
    conn.putheader("Authorization", f"Bearer {TOKEN}")
    conn.putheader("Content-Type", f"multipart/form-data; boundary={BOUNDARY}")
    conn.putheader("Content-Length", str(length))
    conn.endheaders()
    conn.send(start + first)
    return conn


def _spool_files(pid: int, folder: Path) -> list[str]:
    """The files process ``pid`` has open in ``folder`` (a spool file is unnamed: ``#inode
    (deleted)`` or ``tmpXXXX (deleted)``)."""
    out = []
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith(str(folder.resolve()) + "/"):
            out.append(target)
    return out


def test_a_body_the_disk_cannot_take_is_refused_before_it_is_read(tight_server):
    """6 GiB declared, 4 GiB of room: 507 with the reason at once, the body unread (today's
    main read on, to spool it, and answered 408 when the body stopped coming)."""
    conn = _begin_upload(tight_server, 6 * GiB, b"\x93NUMPY")
    r = conn.getresponse()
    detail = r.read().decode()
    conn.close()
    assert r.status == 507, detail
    assert f"the upload's body holds {6 * GiB} bytes" in detail, detail
    assert "upload refused (507) before its body was spooled" in tight_server.log.read_text()


def test_a_body_without_content_length_is_refused_with_a_true_reason(tight_server):
    """A chunked body (no ``Content-Length``) is admitted for the upload limit plus its multipart
    allowance (8 GiB + 1 MiB here, 4 GiB of room): 507, the reason saying so and what to do
    (today's main said "the upload's body holds 8 GiB + 1 MiB bytes", of a body it had not seen)."""
    from fpscan.service.api.upload_limit import MULTIPART_ALLOWANCE

    conn = http.client.HTTPConnection("127.0.0.1", tight_server.port, timeout=HANG_S)
    conn.putrequest("POST", "/api/datasets")
    conn.putheader("Authorization", f"Bearer {TOKEN}")
    conn.putheader("Content-Type", f"multipart/form-data; boundary={BOUNDARY}")
    conn.putheader("Transfer-Encoding", "chunked")
    conn.endheaders()
    start = f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="format"\r\n\r\nnpy\r\n'.encode()
    conn.send(f"{len(start):x}\r\n".encode() + start + b"\r\n")
    r = conn.getresponse()
    detail = r.read().decode()
    conn.close()
    assert r.status == 507, detail
    assert (f"an upload without Content-Length is admitted for up to {8 * GiB + MULTIPART_ALLOWANCE} bytes"
            in detail), detail
    assert "send its Content-Length" in detail and "body holds" not in detail, detail


def test_a_body_is_spooled_in_the_data_folder_and_counted(tight_server):
    """A 3 GiB upload half sent: its spool file is open in ``<data_dir>/incoming``, none in the
    server's TMPDIR, and its 3 GiB are reserved: a second 3 GiB upload, which alone would fit
    the 4 GiB of room, is refused with 507 naming what uploads in progress reserved (today's
    main spooled to TMPDIR uncounted and read the second one's body)."""
    pid = tight_server.service.pid
    incoming = tight_server.data_dir / "incoming"
    first = _begin_upload(tight_server, 3 * GiB, b"\0" * (4 * 2**20))  # past the 1 MiB kept in memory
    try:
        deadline = time.monotonic() + HANG_S
        while not _spool_files(pid, incoming) and time.monotonic() < deadline:  # the server opens its spool file
            time.sleep(0.01)
        assert _spool_files(pid, incoming), "no spool file in the data folder"
        assert not _spool_files(pid, tight_server.spool)
        second = _begin_upload(tight_server, 3 * GiB, b"")
        r = second.getresponse()
        detail = r.read().decode()
        second.close()
        assert r.status == 507, detail
        assert "reserved by uploads, imports and exports in progress" in detail, detail
    finally:
        first.close()


@pytest.fixture
def server(tmp_path):
    srv = Server(tmp_path / "data").start()
    yield srv
    srv.stop()


@pytest.mark.serial
def test_a_spool_that_fails_answers_507_and_is_logged(server, tmp_path):
    """The server may write files of at most 8 MiB (RLIMIT_FSIZE, as a disk that fills up
    mid-upload): a 24 MiB upload's spool fails while it is written: 507 with the reason,
    and a log line; the server goes on (a small upload is stored after it)."""
    limit = 8 * 2**20
    psutil.Process(server.service.pid).rlimit(psutil.RLIMIT_FSIZE, (limit, limit))
    big = io.BytesIO()
    np.save(big, np.zeros((6 * 2**20,), np.float32))
    with server.client(timeout=HANG_S) as api:
        r = api.post("/api/datasets", files={"file": ("big.npy", big.getvalue())},
                     data={"format": "npy", "dt": "1e-8", "dx": "1e-4"})
        assert r.status_code == 507, r.text
        assert "could not be spooled into the data folder (File too large" in r.json()["detail"], r.text
        assert "upload refused (507), its spool failed" in server.log.read_text()
        small = io.BytesIO()
        np.save(small, np.zeros((64, 8), np.float32))
        ok = api.post("/api/datasets", files={"file": ("small.npy", small.getvalue())},
                      data={"format": "npy", "dt": "1e-8", "dx": "1e-4"})
        assert ok.status_code == 201, ok.text
