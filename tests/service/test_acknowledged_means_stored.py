"""Acknowledged means stored: an upload answered ``201 deduplicated: true``
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

The other acknowledge-then-delete pairs race 200 times each as well: a reconstruction
against the deletion of its dataset, a download or an export against the deletion of its
job, a scan against the deletion of its plan (``lifecycle.create_job`` against
``lifecycle.delete_plan``), and a plan stored again (same content, same id) against its
deletion. Each test prints how many races ended each way.
"""
from __future__ import annotations

import http.client
import io
import json
import os
import random
import select
import shutil
import uuid

import httpx
import numpy as np
import pytest

from tests.service.service_servers import TOKEN, Server, needs_recon, wait_job
from tests.waits import HANG_S

pytestmark = pytest.mark.long(50)

RACES = 200
JOB_RACES = 200
DOWNLOAD_RACES = 200
PLAN_RACES = 200


def npy_bytes(offset: int = 0) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.arange(16 * 4 * 4, dtype=np.float32).reshape(16, 4, 4) + offset)
    return buf.getvalue()


def upload_form(offset: int = 0) -> dict:
    return {"data": {"format": "npy", "dt": "2e-8", "dx": "1e-4"}, "files": {"file": ("d.npy", npy_bytes(offset))}}


def clone_datasets(data_dir, dataset_id: str, n: int) -> list[str]:
    """``n`` more stored copies of ``dataset_id`` (folder and row; the server stopped),
    newer than it, oldest first."""
    from fpscan.service.jobs.store import JobStore

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
    (200, and the job is refused with 404), never both while the job is active (a queued job
    whose input is gone). The one way both are acknowledged rightly: the job ran to its end
    before the deletion was served (a 16 x 4 x 4 NER takes milliseconds, and a loaded machine
    can serve the deletion later than that); such a job succeeded, having read its input,
    where a job whose input went first fails without it."""
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
                if job_status == 202 and rm_status == 200:
                    ended = wait_job(api, job_body["id"])
                    if ended["state"] != "succeeded":  # its input went before it ran
                        both.append((i, victim, ended["state"]))
                elif job_status == 202:
                    api.post(f"/api/jobs/{job_body['id']}/cancel")  # no reconstruction runs for the test
                else:
                    assert (job_status, rm_status) == (404, 200), (job_status, job_body, rm_status, rm_body)
                    assert "no dataset" in job_body["detail"], job_body
    finally:
        job.close()
        rm.close()
    print(f"{JOB_RACES} races (reconstruction, deletion): {outcomes}; both acknowledged, the job not run to its "
          f"end first: {len(both)}")
    assert not both, f"{len(both)} of {JOB_RACES} races queued a job and deleted its dataset: {both[:5]}"


def clone_jobs(data_dir, job_id: str, n: int) -> list[str]:
    """``n`` more succeeded copies of the reconstruction ``job_id`` (its row through the
    store's own calls, its result folder copied; the server stopped)."""
    from fpscan.service.jobs.store import JobStore

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
    """Results and exports: ``GET`` of a volume or an export racing ``DELETE``
    of its job is answered with the whole file as it was (200) or 404, never a 500 (the
    file is opened by the route: ``fpscan.service.api.files.HeldFileResponse``)."""
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


PLAN = {"lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4}, "points": [[0, 0], [1, 1], [2, 2]],
        "acquisition": {"n_t": 64, "dt": 2e-8, "prf": 100.0}}


@pytest.fixture(scope="module")
def stuck_scanner(tmp_path_factory):
    """A server whose one scanner is a pseudo-terminal nobody answers: a scan queued on it
    stays active (queued behind the first, which waits on the silent device), so a scan's
    202 and its plan's deletion can never both be right."""
    master, slave = os.openpty()
    srv = Server(tmp_path_factory.mktemp("plans") / "data", devices={"mute": os.ttyname(slave)}).start()
    yield srv
    srv.stop()
    os.close(master)
    os.close(slave)


def _race(rng: random.Random, sends: list) -> bool:
    """Send ``sends`` (connection, method, path, body, headers), in a random order a random
    fraction of a millisecond apart; whether the second one's answer (``sends[1]``) could be
    read alone before the first's."""
    order = list(sends)
    if rng.random() < 0.5:
        order.reverse()
    for k, (conn, method, path, payload, headers) in enumerate(order):
        conn.request(method, path, body=payload, headers=headers)
        if k == 0:
            select.select([], [], [], rng.random() * 2e-3)
    readable, _, _ = select.select([sends[0][0].sock, sends[1][0].sock], [], [], HANG_S)
    return sends[1][0].sock in readable and sends[0][0].sock not in readable


@pytest.mark.timeout(300)
def test_a_scan_and_the_deletion_of_its_plan_never_both_succeed(stuck_scanner):
    """The plan's acknowledge-then-delete pair (``fpscan.service.jobs.lifecycle.create_job`` against
    ``delete_plan``): ``POST /api/scans`` (202: the scan will read the plan) racing
    ``DELETE /api/plans/{id}``. Either the scan came first (202, its job exists and is
    active, and the deletion is refused with 409 naming it) or the deletion did (200, and the
    scan is refused with 404 naming the plan), never both."""
    srv = stuck_scanner
    rng = random.Random(63)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    scan = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    rm = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    outcomes: dict[tuple[int, int], int] = {}
    both = []
    try:
        with srv.client() as api:
            # a first scan, of another plan, holds the mute scanner for the whole test
            other = api.post("/api/plans", json={**PLAN, "points": [[3, 3]]}).json()["id"]
            blocker = api.post("/api/scans", json={"plan_id": other, "scanner_id": "mute"}).json()["id"]
            for i in range(PLAN_RACES):
                r = api.post("/api/plans", json=PLAN)  # (again: same content, same id)
                assert r.status_code == 201, r.text
                plan_id = r.json()["id"]
                body = json.dumps({"plan_id": plan_id, "scanner_id": "mute"})
                _race(rng, [(scan, "POST", "/api/scans", body, {**auth, "Content-Type": "application/json"}),
                            (rm, "DELETE", f"/api/plans/{plan_id}", None, auth)])
                scan_status, scan_body = answer(scan)
                rm_status, rm_body = answer(rm)
                key = (scan_status, rm_status)
                outcomes[key] = outcomes.get(key, 0) + 1
                plan_there = api.get(f"/api/plans/{plan_id}").status_code == 200
                if scan_status == 202:
                    job = api.get(f"/api/jobs/{scan_body['id']}").json()
                    if rm_status == 200 or not plan_there:
                        both.append((i, key, job["state"], plan_there))
                    else:
                        assert rm_status == 409 and scan_body["id"] in rm_body["detail"], (i, rm_body)
                        assert job["state"] in ("queued", "running", "paused"), job
                    assert api.post(f"/api/jobs/{scan_body['id']}/cancel").status_code == 200
                    wait_job(api, scan_body["id"])  # cancelled: the plan is free for the next race
                else:
                    assert key == (404, 200), (i, scan_body, rm_body)
                    assert "no plan" in scan_body["detail"] and not plan_there, (i, scan_body, plan_there)
            api.post(f"/api/jobs/{blocker}/cancel")
    finally:
        scan.close()
        rm.close()
    print(f"{PLAN_RACES} races (scan, plan deletion): {outcomes}; both acknowledged: {len(both)}")
    assert not both, f"{len(both)} of {PLAN_RACES} races queued a scan and deleted its plan: {both[:5]}"


@pytest.mark.timeout(300)
def test_a_plan_answered_201_is_not_deleted_before_its_answer(stuck_scanner):
    """Plans are stored by content (same plan, same id): ``POST /api/plans`` of a stored
    plan racing ``DELETE /api/plans/{id}``. A deletion whose answer could be read before the
    201's came first, so the plan the 201 names must exist afterwards (stored again); one
    answered after the 201 may remove it."""
    srv = stuck_scanner
    rng = random.Random(64)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    plan = {**PLAN, "points": [[1, 2], [2, 1]]}
    post = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    rm = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=HANG_S)
    seen = {"deletion answered first": 0, "plan answered first": 0, "plan there afterwards": 0,
            "plan gone afterwards": 0}
    lost = []
    try:
        with srv.client() as api:
            for i in range(PLAN_RACES):
                r = api.post("/api/plans", json=plan)
                assert r.status_code == 201, r.text
                plan_id = r.json()["id"]
                deletion_alone_first = _race(
                    rng, [(post, "POST", "/api/plans", json.dumps(plan), {**auth, "Content-Type": "application/json"}),
                          (rm, "DELETE", f"/api/plans/{plan_id}", None, auth)])
                post_status, post_body = answer(post)
                rm_status, rm_body = answer(rm)
                assert post_status == 201 and post_body["id"] == plan_id, (post_status, post_body)
                assert rm_status == 200, (rm_status, rm_body)
                there = api.get(f"/api/plans/{plan_id}").status_code == 200
                seen["deletion answered first" if deletion_alone_first else "plan answered first"] += 1
                seen["plan there afterwards" if there else "plan gone afterwards"] += 1
                if deletion_alone_first and not there:
                    lost.append(i)
    finally:
        post.close()
        rm.close()
    print(f"{PLAN_RACES} races (plan, plan deletion): {seen}; acknowledged then lost: {len(lost)}")
    assert not lost, f"{len(lost)} of {PLAN_RACES} plans answered 201 were deleted before the answer: {lost[:5]}"
