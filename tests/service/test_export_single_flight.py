"""Exports are single-flight: 20
concurrent first requests of one job's OME-TIFF wait for one build, and every response
carries the same bytes, with one OME UUID (tifffile writes a new UUID per file, so two
builds differ there), on a real server; then the job's deletion leaves none of its
export behind.
"""
from __future__ import annotations

import hashlib
import io
import re
import threading
import time

import numpy as np
import pytest

from tests.service.service_servers import Server, needs_recon, wait_job

pytestmark = [needs_recon, pytest.mark.timeout(300)]

CONCURRENT = 20


def test_concurrent_first_exports_wait_for_one_build_and_serve_the_same_bytes(tmp_path):
    import tifffile

    data = tmp_path / "data"
    # 4 export builds at once and 16 waiting: room for the 20 requests (the admission counts the
    # requests waiting for another's build too: tests/service/test_export_bounds.py)
    srv = Server(data, env={"FPSCAN_EXPORT_WORKERS": "4"}).start()
    try:
        with srv.client() as api:
            buf = io.BytesIO()
            np.save(buf, np.random.default_rng(7).standard_normal((48, 8, 8)).astype(np.float32))
            r = api.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                         files={"file": ("d.npy", buf.getvalue())})
            assert r.status_code == 201, r.text
            r = api.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "ner"})
            assert r.status_code == 202, r.text
            job = wait_job(api, r.json()["id"])
            assert job["state"] == "succeeded", job
        jid = job["id"]
        assert not list(data.glob(f"results/{jid}.*/volume.ome.tif"))  # no export yet: these are first requests

        answers: list[tuple[int, bytes]] = []
        gate = threading.Barrier(CONCURRENT)

        def fetch() -> None:
            with srv.client() as c:
                gate.wait()
                resp = c.get(f"/api/jobs/{jid}/export/ome-tiff")
                answers.append((resp.status_code, resp.content))

        threads = [threading.Thread(target=fetch) for _ in range(CONCURRENT)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert [s for s, _ in answers] == [200] * CONCURRENT, [s for s, _ in answers]
        digests = {hashlib.sha256(body).hexdigest() for _, body in answers}
        uuids = set()
        for _, body in answers:
            with tifffile.TiffFile(io.BytesIO(body)) as tif:
                uuids |= set(re.findall(r'UUID="(urn:uuid:[0-9a-f-]+)"', tif.ome_metadata))
        print(f"{CONCURRENT} concurrent first OME-TIFF exports: {len(digests)} distinct bodies, {len(uuids)} UUIDs")
        assert len(uuids) == 1 and len(digests) == 1, (uuids, len(digests))
        # a Range request resumes the same file
        with srv.client() as api:
            body = answers[0][1]
            part = api.get(f"/api/jobs/{jid}/export/ome-tiff", headers={"Range": f"bytes={len(body) // 2}-"})
            assert part.status_code == 206 and part.content == body[len(body) // 2:]
            head = api.head(f"/api/jobs/{jid}/export/ome-tiff")  # the same file's headers, no body
            assert head.status_code == 200 and int(head.headers["content-length"]) == len(body) and not head.content
            # the job's deletion takes its export with it
            assert api.delete(f"/api/jobs/{jid}").status_code == 200
        assert not list(data.glob(f"results/{jid}*")), list(data.glob(f"results/{jid}*"))
    finally:
        srv.stop()


def test_requests_that_wait_for_a_build_serve_it_and_later_ones_build_anew(tmp_path):
    """The single flight of a scan's export (written anew per request), as the exports hold
    it (``SingleFlight.turn``): the requests that came while it was written serve that build;
    one that comes after builds again."""
    from fpscan.service.api.single_flight import SingleFlight

    flights = SingleFlight()
    out = tmp_path / "x_ipasc.h5"
    building, release = threading.Event(), threading.Event()
    seen: dict[str, bool] = {}

    def first() -> None:
        with flights.turn(out) as turn:
            seen["first"] = turn.built_meanwhile
            building.set()
            release.wait(60)
            turn.built()

    def waiter(name: str) -> None:
        with flights.turn(out) as turn:
            seen[name] = turn.built_meanwhile

    threads = [threading.Thread(target=first)]
    threads[0].start()
    assert building.wait(60)
    threads += [threading.Thread(target=waiter, args=(f"w{i}",)) for i in range(3)]
    for t in threads[1:]:
        t.start()
    deadline = time.monotonic() + 60
    while flights.users(out) < 4 and time.monotonic() < deadline:  # every waiter is in line
        time.sleep(0.01)
    release.set()
    for t in threads:
        t.join(60)
    waiter("later")
    assert seen == {"first": False, "w0": True, "w1": True, "w2": True, "later": False}, seen
    assert flights.users(out) == 0  # the entry went with its last user
