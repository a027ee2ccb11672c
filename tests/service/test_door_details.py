"""The door's details (found in review): plan reads that draw or compress
in the plan worker are counted in like plan requests (429 when the slots are full, never a
queue without bound); ``allowed_hosts = ["*"]`` opens no door without a token; gzip only
where the client accepts it; a dataset stored with ``force`` is not handed to an upload
without it; retention by bytes removes the least recently used dataset; lengths, times and
speeds typed with units in the upload form and the reconstruction options.

Real ``fpscan serve`` processes on 127.0.0.1 (``service_servers.Server``)."""
from __future__ import annotations

import io
import socket
import time

import numpy as np
import pytest

from fpscan.service.api.access import host_allowed
from fpscan.service.api.plans import accepts_encoding
from fpscan.service.settings import Settings
from tests.service.service_servers import Server
from tests.waits import HANG_S

DT, PITCH = 2e-8, 1e-4


def _npy(seed: int) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(seed).standard_normal((32, 6, 6)).astype(np.float32))
    return buf.getvalue()


@pytest.fixture(scope="module")
def open_server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("door") / "data").start()
    yield srv
    srv.stop()


def test_plan_reads_are_counted_in_and_refused_when_the_plan_slots_are_full(tmp_path):
    srv = Server(tmp_path / "data", env={"FPSCAN_BODY_TIMEOUT_S": "60"}).start()
    stalled: list[socket.socket] = []
    try:
        with srv.client() as api:
            r = api.post("/api/plans", json={"kind": "full", "lattice": {"n_x": 8, "n_y": 8, "pitch": 1e-4}})
            assert r.status_code == 201, r.text
            pid = r.json()["id"]
            assert api.get(f"/api/plans/{pid}/preview.png").status_code == 200
            # token holders whose plan requests stall: every plan slot (1 running + 8 waiting)
            # taken, from two addresses (one address may hold all but 2 of them: slots go per client)
            port = int(srv.url.rsplit(":", 1)[1])

            def stall() -> None:
                source = f"127.0.0.{2 + len(stalled) // 7}"
                s = socket.create_connection(("127.0.0.1", port), timeout=10, source_address=(source, 0))
                s.sendall(f"POST /api/plans HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 100000\r\n"
                          f"Authorization: Bearer {srv.token}\r\nContent-Type: application/json\r\n\r\n{{".encode())
                stalled.append(s)

            for _ in range(9):
                stall()
            # a read that got in found room (the server had not yet counted every stalled
            # request, or one was refused while the read was inside): one more stalled request
            # each time, until the plan slots are full and the read is refused
            deadline = time.monotonic() + HANG_S
            while (r := api.get(f"/api/plans/{pid}/preview.png")).status_code == 200:
                assert time.monotonic() < deadline, "preview.png was never refused while the plan slots were full"
                stall()
            assert r.status_code == 429 and "plan requests" in r.json()["detail"], r.text
            assert r.headers.get("retry-after")
            assert api.get("/api/health").status_code == 200
            for s in stalled:
                s.close()
            stalled.clear()
            # the slots free again once the strangers are gone (their connections closed)
            deadline = time.monotonic() + HANG_S
            while (r := api.get(f"/api/plans/{pid}/preview.png")).status_code == 429:
                assert time.monotonic() < deadline, r.text
                time.sleep(0.1)
            assert r.status_code == 200 and r.content.startswith(b"\x89PNG"), r.text
    finally:
        for s in stalled:
            s.close()
        srv.stop()


def test_any_host_name_needs_a_token(tmp_path):
    token_file = tmp_path / "token"
    token_file.write_text("s3cret-token-value")
    open_ = Settings(data_dir=tmp_path / "a", allowed_hosts=["*"])
    guarded = Settings(data_dir=tmp_path / "b", allowed_hosts=["*"], token_file=token_file)
    assert not host_allowed("evil.example", open_)  # DNS rebinding stays shut without a token
    assert host_allowed("localhost", open_) and host_allowed("127.0.0.1", open_)
    assert host_allowed("evil.example", guarded)
    named = Settings(data_dir=tmp_path / "c", allowed_hosts=["scanner-pc.lab"])
    assert host_allowed("scanner-pc.lab", named) and not host_allowed("other.lab", named)


@pytest.mark.parametrize("header, ok", [("gzip", True), ("gzip, deflate, br", True), ("GZIP;q=0.5", True),
                                        ("gzip;q=0", False), ("deflate", False), ("", False), ("*", True),
                                        ("*;q=0", False), ("br, gzip;q=0.0", False), ("gzip;q=bad", False)])
def test_accepts_encoding_follows_the_quality_values(header, ok):
    assert accepts_encoding(header, "gzip") is ok


def test_a_forced_dataset_is_not_handed_to_an_upload_without_force(open_server):
    with open_server.client() as api:
        body = _npy(1)
        form = {"format": "npy", "dt": "20ns", "dx": "100um", "c": "2.5 km/s"}
        r = api.post("/api/datasets", data={**form, "force": "true"}, files={"file": ("d.npy", body)})
        assert r.status_code == 201, r.text
        forced = r.json()
        # the same bytes and numbers without force: the speed rule refuses it (not the stored copy)
        r = api.post("/api/datasets", data=form, files={"file": ("d.npy", body)})
        assert r.status_code == 422 and "m/s" in r.json()["detail"], r.text
        # with force again: the stored one
        r = api.post("/api/datasets", data={**form, "force": "true"}, files={"file": ("d.npy", body)})
        assert r.status_code == 201 and r.json()["dataset_id"] == forced["dataset_id"], r.text
        assert r.json().get("deduplicated") is True


def test_upload_form_and_recon_options_take_units(open_server):
    with open_server.client() as api:
        r = api.post("/api/datasets", data={"format": "npy", "dt": "20 ns", "dx": "0.1mm"},
                     files={"file": ("u.npy", _npy(2))})
        assert r.status_code == 201, r.text
        ds = r.json()
        assert ds["dt"] == pytest.approx(DT)
        r = api.post("/api/datasets", data={"format": "npy", "dt": "20 furlongs", "dx": "0.1mm"},
                     files={"file": ("u.npy", _npy(2))})
        assert r.status_code == 422 and "dt" in r.json()["detail"], r.text
        r = api.post("/api/reconstructions", json={"dataset_id": ds["dataset_id"], "method": "ner",
                                                   "params": {"dz": "30um", "c": "1.5 km/s"}})
        assert r.status_code == 202, r.text
        params = api.get(f"/api/jobs/{r.json()['id']}").json()["params"]["params"]
        assert params["dz"] == pytest.approx(30e-6) and params["sound_speed"] == pytest.approx(1500.0), params
        r = api.post("/api/reconstructions", json={"dataset_id": ds["dataset_id"], "method": "ner",
                                                   "params": {"dz": "30 furlongs"}})
        assert r.status_code == 422 and "dz" in r.text, r.text


def test_retention_by_bytes_removes_the_least_recently_used_dataset(tmp_path):
    srv = Server(tmp_path / "data").start()
    try:
        _retention_lru(srv)
    finally:
        srv.stop()


def _retention_lru(srv: Server) -> None:
    with srv.client() as api:
        first_body, second_body = _npy(11), _npy(12)
        up = {"format": "npy", "dt": repr(DT), "dx": repr(PITCH)}
        first = api.post("/api/datasets", data=up, files={"file": ("a.npy", first_body)}).json()["dataset_id"]
        second = api.post("/api/datasets", data=up, files={"file": ("b.npy", second_body)}).json()["dataset_id"]
        again = api.post("/api/datasets", data=up, files={"file": ("a.npy", first_body)}).json()
        assert again["dataset_id"] == first and again["deduplicated"]  # asked for again: used most recently
        sizes = {d["dataset_id"]: d["size_bytes"] for d in api.get("/api/datasets").json()}
        r = api.put("/api/retention", json={"datasets_keep_bytes": max(sizes.values()) + 1})
        assert r.status_code == 200, r.text
        left = [d["dataset_id"] for d in api.get("/api/datasets").json()]
        assert left == [first], (left, first, second)  # created first, used last: kept
        assert api.put("/api/retention", json={"datasets_keep_bytes": None}).status_code == 200
