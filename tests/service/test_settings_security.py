"""Settings (environment + file), the token rule beyond loopback, the web page, memory
admission queueing and restart recovery of the job store (real SQLite file)."""
from __future__ import annotations

import io
import json
import sqlite3
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from fpscan.clients.processes import free_port
from fpscan.service.jobs.store import JobStore
from fpscan.service.settings import Settings, is_loopback
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.waits import HANG_S


def test_settings_file_environment_and_overrides(tmp_path, monkeypatch):
    f = tmp_path / "fpscan.toml"
    f.write_text('data_dir = "/srv/fp"\ntoken = "from-file"\nworkers = 3\n[devices]\nfp1 = "/dev/ttyACM0"\n')
    monkeypatch.setenv("FPSCAN_WORKERS", "2")
    s = Settings.load(f)
    assert str(s.data_dir) == "/srv/fp" and s.token_value() == "from-file"
    assert s.devices == {"fp1": "/dev/ttyACM0"}
    assert s.workers == 2  # the environment beats the file
    assert Settings.load(f, workers=5).workers == 5  # explicit beats both
    assert s.database == s.data_dir / "jobs.sqlite"
    j = tmp_path / "s.json"
    j.write_text(json.dumps({"memory_limit": 1234, "dask_scheduler": "tcp://10.0.0.1:8786"}))
    s = Settings.load(j)
    assert s.memory_limit == 1234 and s.executor == "dask"
    for bad in ({"workers": 0}, {"devices": {"../x": "/dev/null"}}, {"executor": "dask"}, {"port": 70000}):
        with pytest.raises(ValueError):
            Settings(**bad)
    (tmp_path / "bad.json").write_text("{nope")
    with pytest.raises(ValueError, match="not valid"):
        Settings.load(tmp_path / "bad.json")
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")


def test_beyond_loopback_everything_needs_the_token_and_web_page_is_served(tmp_path):
    import uvicorn

    from fpscan.service.api.app import create_app

    web = tmp_path / "web"
    web.mkdir()
    (web / "index.html").write_text("<html><body>fpscan page</body></html>")
    # the settings say 0.0.0.0 (a public bind); the test itself listens on 127.0.0.1 only
    settings = Settings(data_dir=tmp_path / "d", host="0.0.0.0", token="s3cret", web_root=web)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(settings, start_workers=False), host="127.0.0.1",
                                           port=port, log_level="warning"))
    t = threading.Thread(target=server.run, daemon=True)
    t.start()
    try:
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + HANG_S
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        r = httpx.get(url + "/api/health")
        assert r.status_code == 401 and r.json()["detail"] == "missing bearer token"
        assert httpx.get(url + "/api/jobs").status_code == 401
        assert httpx.get(url + "/api/jobs", headers={"Authorization": "Bearer nope"}).status_code == 401
        assert httpx.get(url + "/api/health", headers={"Authorization": "Bearer s3cret"}).status_code == 200
        page = httpx.get(url + "/")
        assert page.status_code == 200 and "fpscan page" in page.text
        assert httpx.get(url + "/../../etc/passwd").status_code == 404
    finally:
        server.should_exit = True
        t.join(timeout=HANG_S)


def test_restart_recovery_in_the_store(tmp_path):
    db = tmp_path / "jobs.sqlite"
    store = JobStore(db)
    recon, _ = store.create_job("recon", {"x": 1})
    scan, _ = store.create_job("scan", {"plan_id": "p"})
    tired, _ = store.create_job("recon", {"x": 2})
    waiting, _ = store.create_job("recon", {"x": 3})
    for _ in range(2):  # interrupted twice already
        assert store.claim(tired["id"], "old-server", 10) is not None
        store.recover("another", max_attempts=99)
    for job in (recon, scan, tired):
        assert store.claim(job["id"], "old-server", 10) is not None
    store.update_progress(scan["id"], {"stage": "acquiring", "fraction": 0.2, "eta_s": 3.1})
    store.close()
    # a new server instance opens the same file
    store = JobStore(db)
    out = store.recover("new-server", max_attempts=3)
    assert out == {"requeued": [recon["id"]], "failed": [tired["id"]], "paused": [scan["id"]]}
    assert store.get(recon["id"])["state"] == "queued" and store.get(recon["id"])["attempts"] == 1
    assert store.get(scan["id"])["state"] == "paused"
    assert store.get(scan["id"])["progress"]["stage"] == "interrupted"
    # the scan's attempt ended at the restart: no end is predicted, and a resume times the next attempt
    assert store.get(scan["id"])["progress"].get("eta_s") is None
    assert [a["reason"] for a in store.get(scan["id"])["earlier_attempts"]] == ["server restarted"]
    assert store.get(scan["id"])["started"] is None
    assert store.get(tired["id"])["state"] == "failed"
    assert store.get(waiting["id"])["state"] == "queued"
    events = [e["event"] for e in store.events_after(recon["id"], 0)]
    assert events == ["state", "state", "state"]  # queued, running, queued again
    store.close()
    raw = sqlite3.connect(db)
    assert raw.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    raw.close()


def test_the_store_lists_a_page_before_a_job_and_a_scans_reconstructions(tmp_path):
    store = JobStore(tmp_path / "jobs.sqlite")
    scan, _ = store.create_job("scan", {"plan_id": "p"})
    other, _ = store.create_job("scan", {"plan_id": "q"})
    mine = [store.create_job("recon", {"scan_job_id": scan["id"], "x": k})[0]["id"] for k in range(3)]
    theirs = store.create_job("recon", {"scan_job_id": other["id"]})[0]["id"]
    newest = [j["id"] for j in store.list()]
    assert newest == [theirs, *mine[::-1], other["id"], scan["id"]]
    assert [j["id"] for j in store.list(limit=2, before=newest[1])] == newest[2:4]
    assert store.list(before="no-such-job") == []
    assert [j["id"] for j in store.list(kind="recon", scan_job_id=scan["id"])] == mine[::-1]
    assert [j["id"] for j in store.list(scan_job_id=other["id"], before=theirs)] == []
    store.close()


def test_an_idempotent_repeat_compares_the_request_not_what_the_server_worked_out(tmp_path):
    """The same Idempotency-Key and request after a restart whose settings spell the data folder
    otherwise, or change an estimate, is the same job (it was a 409); another request is still a 409."""
    from fpscan.service.jobs.store import IdempotencyConflict

    store = JobStore(tmp_path / "jobs.sqlite")
    asked = {"method": "ner", "params": {"n_z": 16}, "dataset_id": "d1", "input_id": "dataset:d1"}
    keys = ("method", "params", "dataset_id", "input_id")
    first, created = store.create_job("recon", {**asked, "input": {"path": "data/datasets/d1/dataset.h5"},
                                                "work_estimate_s": 1.5}, idempotency_key="k", request_keys=keys)
    again, created_again = store.create_job("recon", {**asked, "input": {"path": "/srv/data/datasets/d1/dataset.h5"},
                                                      "work_estimate_s": 0.7}, idempotency_key="k", request_keys=keys)
    assert created and not created_again and again["id"] == first["id"]
    with pytest.raises(IdempotencyConflict):
        store.create_job("recon", {**asked, "params": {"n_z": 32}}, idempotency_key="k", request_keys=keys)
    store.close()
    # the data folder is kept absolute: the jobs' records name their files by it
    assert Settings(data_dir="fpscan-data").data_dir == Path.cwd() / "fpscan-data"
    assert Settings(data_dir="~/d").data_dir == Path.home() / "d"


def _npy(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


@needs_recon
def test_memory_admission_queues_what_does_not_fit_now(tmp_path):
    from fpscan.service.jobs.admission import estimate_memory

    shape = (256, 48, 48)
    est = estimate_memory({"n_t": shape[0], "n_x": shape[2], "n_y": shape[1]},
                          {"method": "ner", "dtype": "float64"})
    # room for one such job at a time, and two workers that could run both
    srv = Server(tmp_path / "adm", env={"FPSCAN_MEMORY_LIMIT": str(int(est * 1.5)), "FPSCAN_WORKERS": "2"}).start()
    try:
        with srv.client() as c:
            ds = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                        files={"file": ("a.npy", _npy(np.ones(shape, np.float32)), "x")}).json()["dataset_id"]
            body = {"dataset_id": ds, "method": "ner", "params": {"dtype": "float64"}}
            ids = [c.post("/api/reconstructions", json=body).json()["id"] for _ in range(2)]
            jobs = [wait_job(c, j) for j in ids]
            assert [j["state"] for j in jobs] == ["succeeded", "succeeded"]
            first, second = sorted(jobs, key=lambda j: j["timings"]["started"])
            assert second["timings"]["started"] >= first["timings"]["finished"]
            assert second["params"]["memory_estimate"] <= int(est * 1.5) < 2 * second["params"]["memory_estimate"]
    finally:
        srv.stop()


@pytest.mark.parametrize("argv, env, reason", [
    (["--device", "foo"], {}, "ID=PATH"),
    (["--host", "0.0.0.0"], {}, "needs a --token"),
    (["--allowed-host", "*"], {}, "needs a --token"),
    (["--allowed-host", "http://evil.example/"], {}, "allowed host"),
    ([], {"FPSCAN_WORKERS": "0"}, "workers"),
    (["--settings", "/nonexistent/fpscan.toml"], {}, "cannot read settings file"),
])
def test_fpscan_serve_refuses_bad_settings_with_one_line(argv, env, reason, tmp_path):
    import os
    import subprocess
    import sys

    from tests.service.service_servers import REPO

    full_env = {k: v for k, v in os.environ.items() if not k.startswith("FPSCAN_")}
    full_env.update({"FPSCAN_DATA_DIR": str(tmp_path), **env})
    p = subprocess.run([sys.executable, "-m", "fpscan", "serve", "--port", "0", *argv], cwd=REPO, env=full_env,
                       capture_output=True, text=True, timeout=HANG_S)
    assert p.returncode == 2  # refused settings: a usage error
    assert reason in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
