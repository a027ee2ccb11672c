"""A job's event stream lasts the job, at the server's and the clients' default settings:
a real ``fpscan serve`` (body watchdog 30 s, a keep-alive comment after
15 s without an event) and a real simulated scanner on a pty scanning 121 points at 1 Hz,
a job of about two minutes, four times the body watchdog. curl, the sync client and the
async client (each at its default read timeout, 30 s) follow the stream at once from the
scan's start to its final state; the server's log holds no error and no traceback.

`tests/service/test_event_streams.py` holds the same check scaled down (a 4 s scan against a
2 s watchdog) beside the other stream tests; this file holds the two-minute form, marked
``waits``: scripts/test.sh runs it in a lane of its own beside the parallel part (on a test
worker it held that worker and its core idle for two minutes).
"""
from __future__ import annotations

import shutil
import threading
import time

import pytest

from tests.service.service_servers import Server, needs_recon, wait_job
from tests.service.test_event_streams import _async_client, _curl, _sync_client
from tests.service.test_scans import make_plan, phantom, start_scan
from tests.waits import HANG_S

driver_sim = pytest.importorskip("fpscan.driver.simulator")

pytestmark = [needs_recon, pytest.mark.waits]

SIDE, PRF = 11, 1.0  # 121 points at 1 Hz: a scan of about two minutes
DEFAULT_BODY_TIMEOUT_S = 30.0  # fpscan.service.settings.Settings.body_timeout_s
DEFAULT_READ_TIMEOUT_S = 30.0  # fpscan.clients.http.Client.events' read_timeout


@pytest.mark.timeout(600)
@pytest.mark.skipif(shutil.which("curl") is None, reason="needs curl")
def test_a_two_minute_scan_streams_to_its_end_at_the_default_settings(tmp_path):
    from fpscan.driver.sources import BallSource
    from fpscan.service.settings import Settings

    assert Settings.model_fields["body_timeout_s"].default == DEFAULT_BODY_TIMEOUT_S
    sim = driver_sim.SimulatedScanner(source=BallSource(phantom()), prf=PRF, seed=3,
                                      record=tmp_path / "truth.h5").start()
    srv = Server(tmp_path / "data", devices={"sim": sim.path}).start()  # the default settings
    try:
        log0 = srv.log.stat().st_size
        with srv.client() as c:
            job_id = start_scan(c, make_plan(c, n=SIDE, prf=PRF)["id"])
            t0 = time.monotonic()
            curl = _curl(srv, job_id)
            out: dict = {}
            followers = [threading.Thread(target=f, args=(srv, job_id, out, DEFAULT_READ_TIMEOUT_S))
                         for f in (_sync_client, _async_client)]
            for t in followers:
                t.start()
            text, _ = curl.communicate(timeout=HANG_S + 300)
            for t in followers:
                t.join(HANG_S)
            lasted = time.monotonic() - t0
            assert wait_job(c, job_id)["state"] == "succeeded"
        log = srv.log.read_text()[log0:]
    finally:
        srv.stop()
        sim.stop()
    pings = text.count("\n: ping")
    finals = [line for line in text.splitlines() if line.startswith("data:") and '"succeeded"' in line]
    print(f"a {SIDE * SIDE}-point scan at {PRF:g} Hz streamed for {lasted:.1f} s at the default settings: "
          f"curl exit {curl.returncode}, {pings} keep-alive comments, {len(finals)} final state; sync client "
          f"{len(out.get('sync', []))} events, async client {len(out.get('async', []))}; "
          f"server log {len(log)} bytes")
    assert lasted > 3 * DEFAULT_BODY_TIMEOUT_S  # the stream outlived the watchdog several times
    assert curl.returncode == 0 and finals, text[-2000:]
    for name in ("sync", "async"):
        events = out[name]  # absent: that client raised (a dropped stream) and its thread died
        assert events[-1][0] == "state" and events[-1][1]["state"] == "succeeded", (name, events[-3:])
        assert [int(e[2]) for e in events] == sorted({int(e[2]) for e in events}), name  # each once, in order
    assert "error" not in log.lower() and "Traceback" not in log, log[-3000:]
