"""No orphans: a server killed with SIGKILL while it imports an upload leaves no process
behind -- not the import child, not the fork server it came from, not multiprocessing's
resource tracker (today's main left all three, with parent 1, blocked for good).

Oracle: the kernel's process table. A server started by ``start_service`` leads its own
session and every process it starts stays in that session, also once the init process has
adopted it (``tests.rss.session_processes``)."""
from __future__ import annotations

import io
import os
import signal
import threading
import time
from typing import Any

import numpy as np
import psutil
import pytest

from tests.rss import session_processes
from tests.service.service_servers import Server
from tests.waits import HANG_S

KILLS = 20
#: when, after the import child appears, the server is killed: spread over the import's
#: phases (the child starting, reading, asking the disk admission, writing)
KILL_AFTER_S = (0.0, 0.0, 0.01, 0.03)


def _import_child(sid: int) -> psutil.Process | None:
    """A child of the session's fork server (an import child), or None."""
    for p in session_processes(sid):
        try:
            if any("multiprocessing.forkserver" in part for part in p.cmdline()):
                kids = p.children()
                if kids:
                    return kids[0]
        except psutil.Error:
            pass
    return None


def _left_after(sid: int, server: Any) -> list[str]:
    """The session's processes once every one of them has exited (the event), or those still
    there at the deadline, described."""
    if server is not None:
        server.wait(HANG_S)  # reap the killed server: a zombie stays in the process table
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        procs = session_processes(sid)
        if not procs:
            return []
        psutil.wait_procs(procs, timeout=min(5.0, max(deadline - time.monotonic(), 0.0)))
    out = []
    for p in session_processes(sid):
        try:
            out.append(f"{p.pid} (parent {p.ppid()}, {p.memory_info().rss >> 20} MiB): {' '.join(p.cmdline())[:100]}")
        except psutil.Error:
            pass
    return out


def _upload(srv: Server, payload: bytes, answered: threading.Event) -> None:
    try:
        with srv.client(timeout=HANG_S) as api:
            api.post("/api/datasets", files={"file": ("a.npy", payload)}, data={"format": "npy", "dt": "1e-8", "dx": "1e-4"})
    except Exception:  # the server is killed under it
        pass
    finally:
        answered.set()


@pytest.mark.slow
@pytest.mark.serial
@pytest.mark.timeout(3600)
def test_twenty_kills_during_imports_leave_no_process(tmp_path):
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(0).standard_normal((1024, 128, 128)).astype(np.float32))  # 64 MiB
    payload = buf.getvalue()
    during = 0
    for i in range(KILLS):
        srv = Server(tmp_path / f"data{i}").start()
        sid = srv.service.pid
        answered = threading.Event()
        threading.Thread(target=_upload, args=(srv, payload, answered), daemon=True).start()
        child = None
        deadline = time.monotonic() + HANG_S
        while child is None and not answered.wait(0.002) and time.monotonic() < deadline:
            child = _import_child(sid)
        if child is not None:
            answered.wait(KILL_AFTER_S[i % len(KILL_AFTER_S)])
            during += child.is_running() and not answered.is_set()
        os.kill(sid, signal.SIGKILL)
        left = _left_after(sid, srv.service.proc)
        for p in session_processes(sid):  # whatever is left must not outlive the test
            p.kill()
        assert not left, f"kill {i + 1}: {len(left)} processes left: {left}"
    print(f"{KILLS} kill -9 of a server importing an upload ({during} with its import child running): "
          "0 processes left")
    assert during >= KILLS // 4, f"only {during} of {KILLS} kills came while the import child ran"
