"""The results and exports a real ``fpscan serve`` (uvicorn on 127.0.0.1) serves stay within
bounds:

- memory: 9 concurrent exports (OME-TIFF, OME-Zarr, npz) of three 128 MiB result volumes keep
  the server process's peak resident memory (``/proc``, ``tests.rss.RssWatch``) under +300 MB:
  the builds take ``export_workers`` turns, the rest wait, and each streams its volume in slabs;
- disk: an export that would eat into ``disk_reserve_bytes`` is refused with 507 before it is
  written (a real 64 MiB tmpfs); a disk that fills while an export is written (a real tmpfs,
  filled but a slack): every export answers 507 with the free bytes, never 500 (OME-TIFF's
  writer, NumPy's ``tofile``, raises its short write without an errno), the log names the
  exception, and no temporary file or folder is left at any depth;
- admission: requests for one export are counted in before they wait for its build (429
  beyond ``export_workers`` and four times as many waiting);
  a restart removes fpscan's temporaries at any depth of ``results/`` and ``exports/`` (and
  nothing else);
- symbolic links: a result's ``volume.h5``, a picture, an export or the whole result folder
  replaced by a link (to a file outside the data folder) is refused with 404, never served,
  and the refusal logged once per path.

Oracles: the server process's peak RSS read from ``/proc``; the files on disk (``os.walk``); the
HTTP answers; the server's log file.
"""
from __future__ import annotations

import io
import logging
import os
import threading
import time

import h5py
import numpy as np
import pytest

from tests.rss import RssWatch
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.service.small_disks import fill, tmpfs
from tests.waits import HANG_S

pytestmark = [pytest.mark.timeout(600), pytest.mark.long(50)]

MiB = 2**20


def _result_job(c, shape=(64, 16, 16), seed: int = 1) -> str:
    """A succeeded NER reconstruction of a random dataset; its id."""
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(seed).standard_normal(shape).astype(np.float32))
    r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
               files={"file": (f"d{seed}.npy", buf.getvalue())})
    assert r.status_code == 201, r.text
    r = c.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "ner"})
    assert r.status_code == 202, r.text
    job = wait_job(c, r.json()["id"])
    assert job["state"] == "succeeded", job
    return job["id"]


def _result_folder(data, jid: str):
    (folder,) = [p for p in (data / "results").glob(f"{jid}.*") if p.is_dir()]
    return folder


def _temporaries(top) -> list[str]:
    """Every path under ``top`` whose name says it is a temporary (``.tmp``), at any depth."""
    return [os.path.join(d, n) for d, dirs, files in os.walk(top) for n in dirs + files if ".tmp" in n]


@pytest.mark.slow
@needs_recon
def test_nine_concurrent_exports_of_128_mib_volumes_keep_the_server_under_300_mb(tmp_path):
    from fpscan.service.formats.result import write_volume

    data = tmp_path / "data"
    srv = Server(data).start()
    try:
        with srv.client() as c:
            jobs = [_result_job(c, seed=s) for s in range(3)]
        # each result's volume.h5 becomes a 128 MiB volume (512 x 256 x 256 float32), written by the
        # server's own result writer (noise: stored contiguous, as a real reconstruction's)
        rng = np.random.default_rng(3)
        n_z, n_y, n_x = 512, 256, 256
        for jid in jobs:
            p0 = rng.standard_normal((n_z, n_y, n_x), dtype=np.float32)
            write_volume(_result_folder(data, jid) / "volume.h5", p0, np.arange(n_z) * 1e-5,
                         np.arange(n_x) * 1e-4, np.arange(n_y) * 1e-4, method="ner", params={}, input_id=jid)
            del p0
        answers: list[tuple[str, int, int]] = []
        gate = threading.Barrier(9)

        def fetch(jid: str, fmt: str) -> None:
            with srv.client(timeout=HANG_S) as cl:
                gate.wait()
                with cl.stream("GET", f"/api/jobs/{jid}/export/{fmt}") as resp:
                    size = sum(len(b) for b in resp.iter_bytes(1 << 20))
                    answers.append((fmt, resp.status_code, size))

        threads = [threading.Thread(target=fetch, args=(jid, fmt)) for jid in jobs
                   for fmt in ("ome-tiff", "ome-zarr", "npz")]
        with RssWatch(srv.service.pid) as watch:
            for t in threads:
                t.start()
            for t in threads:
                t.join(HANG_S)
        grew = watch.growth / 1e6
        print(f"9 concurrent exports of 128 MiB volumes: server RSS {watch.base / 1e6:.0f} MB before, peak "
              f"{watch.peak / 1e6:.0f} MB (+{grew:.0f} MB); answers {sorted((f, s) for f, s, _ in answers)}")
        assert len(answers) == 9 and all(s == 200 for _, s, _ in answers), answers
        assert all(size > 128 * MiB for fmt, _, size in answers if fmt in ("ome-tiff", "npz")), answers
        assert grew < 300, f"the server grew by {grew:.0f} MB"
    finally:
        srv.stop()


@pytest.fixture
def small_disk(tmp_path):
    with tmpfs(tmp_path / "tmpfs", "64m") as folder:
        yield folder


def test_numpys_errno_less_short_write_on_a_full_disk_is_a_full_disk(small_disk):
    """NumPy's ``tofile`` (tifffile's array writer) raises ``OSError`` without an errno: "N requested
    and M written" for a short write, "Not enough free space to write ..." when its fallocate of
    16 MiB or more fails. Written through ``file_replaced`` on a full disk, the first is an ENOSPC
    error and both count as a full disk; the temporary file is gone."""
    import errno

    from fpscan.service.disk import file_replaced, is_disk_full

    fill(small_disk, leave=64 * 1024)
    with pytest.raises(OSError) as short, file_replaced(small_disk / "a.bin") as tmp, open(tmp, "wb") as fh:
        np.zeros(MiB // 8).tofile(fh)
    assert short.value.errno == errno.ENOSPC and is_disk_full(short.value), repr(short.value)
    assert "requested and" in str(short.value.__cause__), repr(short.value.__cause__)
    with pytest.raises(OSError) as fallocate, open(small_disk / "b.bin", "wb") as fh:
        np.zeros(17 * MiB // 8).tofile(fh)
    assert fallocate.value.errno is None and is_disk_full(fallocate.value), repr(fallocate.value)
    (small_disk / "b.bin").unlink()
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler.bin"]


def test_free_bytes_are_the_disks_and_read_in_one_place(small_disk):
    """``fpscan.service.disk.free_bytes``: the bytes ``statvfs`` gives an unprivileged writer
    (what ``df`` shows as available), None where there is no disk to ask; and it is the one
    look at free space in the server's code."""
    import re
    import subprocess
    from pathlib import Path

    from fpscan.service.disk import free_bytes

    fill(small_disk, leave=3 * MiB)
    df = subprocess.run(["df", "-B1", "--output=avail", str(small_disk)], capture_output=True, text=True, check=True)
    assert free_bytes(small_disk) == int(df.stdout.split()[-1]), df.stdout
    assert 2 * MiB < free_bytes(small_disk) <= 3 * MiB
    assert free_bytes(small_disk / "missing" / "folder") is None
    service = Path(__file__).resolve().parents[2] / "service"
    readers = sorted(str(p.relative_to(service)) for p in service.rglob("*.py")
                     if re.search(r"shutil\.disk_usage|statvfs\(", p.read_text()) and p.name != "disk.py")
    assert readers == [], readers


@needs_recon
def test_an_export_that_would_eat_into_the_disk_reserve_is_refused_up_front(tmp_path, small_disk):
    """The data folder on a 64 MiB disk with 32 MiB kept free (``disk_reserve_bytes``, for
    scans and the job store) and 34 MiB free: every export of a 1.5 MiB volume would fit the
    disk, but not beside the reserve: 507 before a byte is written, the reason naming the
    export's bytes and what is kept free; no temporary, nothing built (today's main wrote them
    into the reserve)."""
    import shutil

    srv = Server(small_disk / "data", env={"FPSCAN_DISK_RESERVE_BYTES": str(32 * MiB)})
    srv.log = tmp_path / "server.log"  # not on the disk that fills
    srv.start()
    try:
        with srv.client() as c:
            jid = _result_job(c, shape=(512, 48, 48))  # a 1.5 MiB volume
            folder = _result_folder(small_disk / "data", jid)
            fill(small_disk, leave=34 * MiB)
            assert shutil.disk_usage(small_disk).free > 30 * MiB  # room for any of the exports, not beside the reserve
            for fmt in ("ome-tiff", "ome-zarr", "npz", "mat"):
                r = c.get(f"/api/jobs/{jid}/export/{fmt}")
                assert r.status_code == 507, (fmt, r.status_code, r.text)
                detail = r.json()["detail"]
                assert f"the {fmt} export of job {jid} may take up to" in detail, detail
                assert f"{32 * MiB} kept free" in detail, detail
            assert _temporaries(small_disk / "data") == []
            assert sorted(p.name for p in folder.iterdir() if p.name.startswith("volume")) == ["volume.h5"]
        log = srv.log.read_text()
        assert sum(f"of job {jid} refused (507) before it was written" in line for line in log.splitlines()) == 4
    finally:
        srv.stop()


@needs_recon
def test_a_full_disk_met_while_writing_answers_every_export_507_and_leaves_no_temporary(tmp_path):
    """A disk that fills while an export is written (another writer took the room the admission
    saw): 507 with the free bytes, never 500, logged with the exception's name, no temporary
    left. Made so here: the result's folder is a small disk of its own (a mount point), filled
    but a slack, while the data folder's disk, which the admission looks at, has room."""
    data = tmp_path / "data"
    srv = Server(data).start()
    try:
        with srv.client() as c:
            jid = _result_job(c, shape=(512, 48, 48))  # a 1.5 MiB volume
            folder = _result_folder(data, jid)
            saved = tmp_path / "saved"
            folder.rename(saved)
            with tmpfs(folder, "16m"):
                for p in saved.iterdir():
                    (folder / p.name).write_bytes(p.read_bytes())
                fill(folder, leave=512 * 1024)  # room for the files' headers, not for their data
                for fmt in ("ome-tiff", "ome-zarr", "npz", "mat"):
                    r = c.get(f"/api/jobs/{jid}/export/{fmt}")
                    assert r.status_code == 507, (fmt, r.status_code, r.text)
                    assert "no room" in r.json()["detail"] and "bytes free" in r.json()["detail"], r.text
                assert _temporaries(data) == []
                assert sorted(p.name for p in folder.iterdir() if p.name.startswith("volume")) == ["volume.h5"]
                log = srv.log.read_text()
                full = [line for line in log.splitlines() if f"of job {jid}: the disk is full" in line]
                print("\n".join(full))
                assert len(full) == 4 and all("OSError" in line for line in full), full
                assert "internal error" not in log
                os.unlink(folder / "filler.bin")
                r = c.get(f"/api/jobs/{jid}/export/ome-tiff")  # room again: exported
                with h5py.File(folder / "volume.h5", "r") as f:
                    volume_bytes = f["p0"].size * 4
                assert r.status_code == 200 and len(r.content) > volume_bytes, (r.status_code, volume_bytes)
    finally:
        srv.stop()


@pytest.mark.slow
@needs_recon
def test_requests_for_one_export_are_counted_before_they_wait_for_its_build(tmp_path):
    """``export_workers`` 1: one request builds a 48 MiB volume's .mat (seconds), 39 more for
    the same export come meanwhile. Four wait for its build, the other 35 are refused at once
    with 429 and ``Retry-After`` (today's main let all 39 wait for the build, each holding a
    thread of the server's pool: 40 concurrent requests of one export held all of AnyIO's 40
    and stalled every other route); a plain route answers while the build runs; the five
    requests let in serve the one build's bytes."""
    from fpscan.service.formats.result import write_volume

    data = tmp_path / "data"
    srv = Server(data, env={"FPSCAN_EXPORT_WORKERS": "1"}).start()
    try:
        with srv.client() as c:
            jid = _result_job(c)
        folder = _result_folder(data, jid)
        n_z, n_y, n_x = 192, 256, 256
        p0 = np.random.default_rng(4).standard_normal((n_z, n_y, n_x), dtype=np.float32)
        write_volume(folder / "volume.h5", p0, np.arange(n_z) * 1e-5, np.arange(n_x) * 1e-4,
                     np.arange(n_y) * 1e-4, method="ner", params={}, input_id=jid)
        del p0
        answers: list[tuple[int, str | None, bytes]] = []
        built = threading.Event()

        def fetch(first: bool = False) -> None:
            with srv.client(timeout=HANG_S) as cl:
                r = cl.get(f"/api/jobs/{jid}/export/mat")
                answers.append((r.status_code, r.headers.get("retry-after"), r.content))
                if first:
                    built.set()

        builder = threading.Thread(target=fetch, args=(True,))
        builder.start()
        deadline = time.monotonic() + HANG_S
        while not [p for p in folder.iterdir() if ".tmp" in p.name] and not built.is_set():
            assert time.monotonic() < deadline, "the build never started"
            time.sleep(0.01)
        assert not built.is_set(), "the build ended before the others came"
        others = [threading.Thread(target=fetch) for _ in range(39)]
        for t in others:
            t.start()
        while sum(s == 429 for s, _, _ in answers) < 35 and not built.is_set():  # the refusals, or the build's end
            assert time.monotonic() < deadline, "no answer"
            time.sleep(0.01)
        with srv.client() as c:
            assert c.get("/api/formats").status_code == 200
        plain_during_build = not built.is_set()
        for t in [builder, *others]:
            t.join(HANG_S)
        refused = [(s, after) for s, after, _ in answers if s == 429]
        served = {body for s, _, body in answers if s == 200}
        print(f"40 requests of one export, export_workers 1: {len(refused)} refused (429), "
              f"{sum(s == 200 for s, _, _ in answers)} served")
        assert len(answers) == 40 and len(refused) == 35, sorted(s for s, _, _ in answers)
        assert all(after is not None and int(after) > 0 for _, after in refused), refused
        assert plain_during_build, "a plain route waited for the build"
        assert len(served) == 1 and len(next(iter(served))) > n_z * n_y * n_x, len(served)
    finally:
        srv.stop()


def test_a_restart_removes_fpscans_temporaries_at_any_depth_and_nothing_else(tmp_path):
    data = tmp_path / "data"
    result = data / "results" / "3f2a9c0d1e4b5a6c.1"
    debris = [
        result / "..volume.ome.zarr.zip.4242.0123456789ab.tmp" / ".volume.ome.zarr.zip.4242.89abcdef0123.tmp"
        / "s0" / "c" / "0",  # an OME-Zarr export's folders in a folder, as a crash leaves them
        result / ".volume.ome.tif.4242.0123456789ab.tmp",
        result / "wavelength_1" / ".volume.h5.4242.fedcba987654.tmp",
        data / "exports" / ".3f2a9c0d1e4b5a6c_ipasc.h5.4242.0123456789ab.tmp",
        data / "results" / "3f2a9c0d1e4b5a6c.2.tmp-4242-123456789" / "volume.h5",
    ]
    kept = [result / "volume.h5", result / "notes.tmp", result / "wavelength_1" / "volume.h5",
            data / "exports" / "3f2a9c0d1e4b5a6c.tmp.h5"]
    for path in debris + kept:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"x")
    old = time.time() - 3600  # left by a process before this start
    for d, dirs, files in os.walk(data):
        for name in dirs + files:
            os.utime(os.path.join(d, name), (old, old))
    srv = Server(data).start()
    try:
        with srv.client() as c:
            assert c.get("/api/health").status_code == 200
        assert sorted(_temporaries(data)) == sorted(str(p) for p in kept if ".tmp" in p.name)
        assert all(p.exists() for p in kept), [p for p in kept if not p.exists()]
    finally:
        srv.stop()


@needs_recon
def test_symbolic_links_planted_in_a_result_are_refused_and_logged_once(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("root:x:0:0:the secret\n" * 4)
    data = tmp_path / "data"
    srv = Server(data).start()
    try:
        with srv.client() as c:
            jid, other = _result_job(c, seed=1), _result_job(c, seed=2)
            folder = _result_folder(data, jid)
            assert c.get(f"/api/jobs/{jid}/export/ome-tiff").status_code == 200  # built: volume.ome.tif
            for name in ("volume.h5", "mip_xy.png", "volume.ome.tif"):
                (folder / name).unlink()
                (folder / name).symlink_to(secret)
            refused = {
                f"/api/reconstructions/{jid}/volume.h5": "volume.h5",
                f"/api/jobs/{jid}/export/result": "volume.h5",
                f"/api/jobs/{jid}/export/npz": "volume.h5",  # a build from a linked source
                f"/api/reconstructions/{jid}/mip/xy.png": "mip_xy.png",
                f"/api/jobs/{jid}/export/ome-tiff": "volume.ome.tif",  # a planted export
                f"/api/reconstructions/{jid}/slice.png": "volume.h5",
            }
            for url in refused:
                for _ in range(3):
                    r = c.get(url)
                    assert r.status_code == 404 and b"secret" not in r.content, (url, r.status_code, r.text)
            # the whole result folder a link to a copy of another's: refused too
            other_folder = _result_folder(data, other)
            moved = other_folder.with_name("elsewhere")
            other_folder.rename(moved)
            other_folder.symlink_to(moved, target_is_directory=True)
            for _ in range(3):
                r = c.get(f"/api/reconstructions/{other}/volume.h5")
                assert r.status_code == 404, (r.status_code, r.text)
        log = srv.log.read_text().splitlines()
        lines = [line for line in log if "refused to serve" in line]
        for name in ("volume.h5", "mip_xy.png", "volume.ome.tif"):
            assert sum(f"{folder.name}/{name}" in line for line in lines) == 1, (name, lines)
        assert sum(f"{other_folder.name}/volume.h5" in line for line in lines) == 1, lines
        assert len(lines) == 4, lines
        assert not any("secret" in line for line in log)
    finally:
        srv.stop()


def test_a_cut_traceback_keeps_the_exceptions_name():
    """The log's cap (2000 characters a record) cuts a long traceback but keeps its last line:
    the exception's name and message."""
    import sys

    from fpscan.service.api.logcaps import CappedRecords

    try:
        try:
            raise ValueError("z" * 5000)  # a long first error: the traceback's head fills the cap
        except ValueError as exc:
            raise OSError("1048576 requested and 131072 written") from exc
    except OSError:
        record = logging.LogRecord("x", logging.ERROR, __file__, 1, "internal error ref=%s", ("ab12",), sys.exc_info())
    assert CappedRecords(limit=2000).filter(record)
    written = logging.Formatter().format(record)
    assert len(written) < 2100 and written.endswith("OSError: 1048576 requested and 131072 written"), written[-300:]
