"""Acknowledged means stored (issue 60.4): an upload answered ``201 deduplicated: true``
names a dataset that exists when the answer is sent, and a deletion racing it either came
first (the upload is answered with another stored copy) or comes after the answer.

The race, 200 times on a real ``fpscan serve`` over two kept-alive loopback connections:
``DELETE /api/datasets/{oldest}`` and an upload of the same bytes, sent a random fraction of
a millisecond apart in either order. The data folder holds 201 stored copies of one dataset
(one upload, its folder and row cloned while the server is stopped), so that every upload
deduplicates (no 1-s import in a race) and each race deletes the copy the upload would
answer with. The oracle is the loopback socket: the server writes an upload's 201 before a
deletion it is serialised before may remove the dataset, so a deletion's answer that can be
read while the upload's cannot means the deletion came first, and the upload must then not
name the deleted dataset. Every dataset a 201 names and the test did not delete must have
its folder on disk.
"""
from __future__ import annotations

import http.client
import io
import json
import random
import select
import shutil
import uuid

import httpx
import numpy as np
import pytest

from tests.service.service_servers import TOKEN, Server, needs_recon, wait_job
from tests.waits import HANG_S

RACES = 200
JOB_RACES = 100
DOWNLOAD_RACES = 60


def npy_bytes(offset: int = 0) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.arange(16 * 4 * 4, dtype=np.float32).reshape(16, 4, 4) + offset)
    return buf.getvalue()


def upload_form(offset: int = 0) -> dict:
    return {"data": {"format": "npy", "dt": "2e-8", "dx": "1e-4"}, "files": {"file": ("d.npy", npy_bytes(offset))}}


def clone_datasets(data_dir, dataset_id: str, n: int) -> list[str]:
    """``n`` more stored copies of ``dataset_id`` (folder and row; the server stopped),
    newer than it, oldest first."""
    from service.jobs.store import JobStore

    store = JobStore(data_dir / "jobs.sqlite")
    try:
        meta = store.get_dataset(dataset_id)
        ids = []
        for _ in range(n):
            new = uuid.uuid4().hex
            shutil.copytree(data_dir / "datasets" / dataset_id, data_dir / "datasets" / new)
            store.put_dataset(new, meta)
            ids.append(new)
        return ids
    finally:
        store.close()


@pytest.fixture(scope="module")
def copies(tmp_path_factory):
    """A server whose data folder holds 1 + RACES copies of one dataset (``"dedup"``) and
    JOB_RACES + 1 of another (``"jobs"``), oldest first."""
    data = tmp_path_factory.mktemp("acknowledged") / "data"
    srv = Server(data).start()
    try:
        with srv.client() as api:
            first = {}
            for name, offset in (("dedup", 0), ("jobs", 1)):
                r = api.post("/api/datasets", **upload_form(offset))
                assert r.status_code == 201, r.text
                first[name] = r.json()["dataset_id"]
    finally:
        srv.stop()
    ids = {"dedup": [first["dedup"], *clone_datasets(data, first["dedup"], RACES)],
           "jobs": [first["jobs"], *clone_datasets(data, first["jobs"], JOB_RACES)]}
    srv.start()
    yield srv, data, ids
    srv.stop()


def answer(conn: http.client.HTTPConnection) -> tuple[int, dict]:
    r = conn.getresponse()
    return r.status, json.loads(r.read() or b"{}")


@pytest.mark.timeout(300)
def test_a_deduplicated_upload_never_names_a_dataset_deleted_before_its_answer(copies):
    srv, data, ids = copies
    copies = ids["dedup"]
    req = httpx.Request("POST", srv.url + "/api/datasets", **upload_form(0))
    upload_body = req.read()
    upload_headers = {"Authorization": f"Bearer {TOKEN}", "Content-Type": req.headers["content-type"]}
    up = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    rm = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    rng = random.Random(60)
    seen = {"deduplicated to the deleted copy": 0, "deduplicated to the next copy": 0,
            "deletion answered first": 0, "upload answered first": 0}
    lost = []
    try:
        for i in range(RACES):
            victim = copies[i]
            upload_first = rng.random() < 0.5
            first_conn, second_conn = (up, rm) if upload_first else (rm, up)
            sends = {up: ("POST", "/api/datasets", upload_body, upload_headers),
                     rm: ("DELETE", f"/api/datasets/{victim}", None, {"Authorization": f"Bearer {TOKEN}"})}
            for conn in (first_conn, second_conn):
                method, path, body, headers = sends[conn]
                conn.request(method, path, body=body, headers=headers)
                if conn is first_conn:
                    spin = rng.random() * 2e-3  # a random fraction of the other's service time
                    select.select([], [], [], spin)
            readable, _, _ = select.select([up.sock, rm.sock], [], [], HANG_S)
            deletion_alone_first = rm.sock in readable and up.sock not in readable
            up_status, up_body = answer(up)
            rm_status, rm_body = answer(rm)
            assert up_status == 201 and up_body.get("deduplicated") is True, (up_status, up_body)
            assert rm_status == 200, (rm_status, rm_body)
            named = up_body["dataset_id"]
            seen["deletion answered first" if deletion_alone_first else "upload answered first"] += 1
            if named == victim:
                seen["deduplicated to the deleted copy"] += 1
                if deletion_alone_first:  # deleted before the 201 was written: acknowledged, then gone
                    lost.append((i, named))
            else:
                seen["deduplicated to the next copy"] += 1
                assert named == copies[i + 1], (i, named)
                if not (data / "datasets" / named).is_dir():
                    lost.append((i, named))
        with srv.client() as api:
            listed = {d["dataset_id"] for d in api.get("/api/datasets").json()} & set(copies)
        assert listed == {copies[RACES]}, listed  # the last copy, which no race deleted
        assert {p.name for p in (data / "datasets").iterdir()} & set(copies) == listed
    finally:
        up.close()
        rm.close()
    print(f"{RACES} races: {seen}; acknowledged then lost: {len(lost)}")
    assert not lost, f"{len(lost)} of {RACES} uploads named a dataset deleted before their answer: {lost[:5]}"


@pytest.mark.timeout(300)
def test_a_reconstruction_and_the_deletion_of_its_dataset_never_both_succeed(copies):
    """The other acknowledge-then-delete pair of a dataset: ``POST /api/reconstructions``
    (202: the job will read it) racing ``DELETE /api/datasets/{id}``. Either the job came
    first (202, and the deletion is refused with 409 while it is active) or the deletion did
    (200, and the job is refused with 404), never both (a queued job whose input is gone)."""
    srv, data, ids = copies
    rng = random.Random(61)
    job = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    rm = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    outcomes: dict[tuple[int, int], int] = {}
    both = []
    try:
        with srv.client() as api:
            for i, victim in enumerate(ids["jobs"][:JOB_RACES]):
                body = json.dumps({"dataset_id": victim, "method": "ner", "params": {"upsample": 1}})
                sends = [(job, "POST", "/api/reconstructions", body, {**auth, "Content-Type": "application/json"}),
                         (rm, "DELETE", f"/api/datasets/{victim}", None, auth)]
                if rng.random() < 0.5:
                    sends.reverse()
                for k, (conn, method, path, payload, headers) in enumerate(sends):
                    conn.request(method, path, body=payload, headers=headers)
                    if k == 0:
                        select.select([], [], [], rng.random() * 2e-3)
                job_status, job_body = answer(job)
                rm_status, rm_body = answer(rm)
                outcomes[(job_status, rm_status)] = outcomes.get((job_status, rm_status), 0) + 1
                if job_status == 202:
                    if rm_status == 200:
                        both.append((i, victim))
                    api.post(f"/api/jobs/{job_body['id']}/cancel")  # no reconstruction runs for the test
                else:
                    assert (job_status, rm_status) == (404, 200), (job_status, job_body, rm_status, rm_body)
                    assert "no dataset" in job_body["detail"], job_body
    finally:
        job.close()
        rm.close()
    print(f"{JOB_RACES} races (reconstruction, deletion): {outcomes}; both acknowledged: {len(both)}")
    assert not both, f"{len(both)} of {JOB_RACES} races queued a job and deleted its dataset: {both[:5]}"


def clone_jobs(data_dir, job_id: str, n: int) -> list[str]:
    """``n`` more succeeded copies of the reconstruction ``job_id`` (its row through the
    store's own calls, its result folder copied; the server stopped)."""
    from service.jobs.store import JobStore

    store = JobStore(data_dir / "jobs.sqlite")
    try:
        job = store.get(job_id)
        ids = []
        for _ in range(n):
            new, _ = store.create_job("recon", job["params"])
            store.claim(new["id"], "test", 10.0)
            folder = data_dir / "results" / f"{new['id']}.1"
            shutil.copytree(job["result_path"], folder)
            assert store.set_state(new["id"], "succeeded", result_path=str(folder), only_from=("running",))
            ids.append(new["id"])
        return ids
    finally:
        store.close()


@needs_recon
@pytest.mark.timeout(300)
def test_a_download_racing_the_deletion_of_its_job_is_whole_or_404_never_500(tmp_path):
    """Results and exports (issue 60.4): ``GET`` of a volume or an export racing ``DELETE``
    of its job is answered with the whole file as it was (200) or 404, never a 500 (the
    file is opened by the route: ``service.api.files.HeldFileResponse``)."""
    data = tmp_path / "data"
    srv = Server(data).start()
    try:
        with srv.client() as api:
            r = api.post("/api/datasets", **upload_form(2))
            r = api.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "ner"})
            job = wait_job(api, r.json()["id"])
            assert job["state"] == "succeeded", job
            volume = api.get(f"/api/reconstructions/{job['id']}/volume.h5").content
    finally:
        srv.stop()
    jobs = clone_jobs(data, job["id"], DOWNLOAD_RACES)
    srv.start()
    rng = random.Random(62)
    get = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    rm = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    outcomes: dict[int, int] = {}
    try:
        for i, jid in enumerate(jobs):
            path = (f"/api/reconstructions/{jid}/volume.h5" if i % 2 else f"/api/jobs/{jid}/export/result")
            sends = [(get, "GET", path), (rm, "DELETE", f"/api/jobs/{jid}")]
            if rng.random() < 0.5:
                sends.reverse()
            for k, (conn, method, url) in enumerate(sends):
                conn.request(method, url, headers=auth)
                if k == 0:
                    select.select([], [], [], rng.random() * 2e-3)
            got = get.getresponse()
            body = got.read()
            rm_status, _ = answer(rm)
            assert rm_status == 200, rm_status
            outcomes[got.status] = outcomes.get(got.status, 0) + 1
            assert got.status in (200, 404), (i, got.status, body[:200])
            if got.status == 200:
                assert body == volume, (i, len(body), len(volume))
            else:
                detail = json.loads(body)["detail"]
                assert "deleted meanwhile" in detail or detail.startswith(("no job", "no recon job")), detail
        left = [p.name for p in (data / "results").iterdir() if p.name.split(".")[0] in jobs]
        assert not left, left  # nothing of a deleted job is left
    finally:
        get.close()
        rm.close()
        srv.stop()
    print(f"{DOWNLOAD_RACES} races (download, deletion): {outcomes}")
