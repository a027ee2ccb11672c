"""The results and exports a real ``fpscan serve`` (uvicorn on 127.0.0.1) serves stay within
bounds:

- memory: 9 concurrent exports (OME-TIFF, OME-Zarr, npz) of three 128 MiB result volumes keep
  the server process's peak resident memory (``/proc``, ``tests.rss.RssWatch``) under +300 MB:
  the builds take ``export_workers`` turns, the rest wait, and each streams its volume in slabs;
- a full disk (a real 64 MiB tmpfs, filled but a slack): every export answers 507 with the free
  bytes, never 500 (OME-TIFF's writer, NumPy's ``tofile``, raises its short write without an
  errno), the log names the exception, and no temporary file or folder is left at any depth;
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

import numpy as np
import pytest

from tests.rss import RssWatch
from tests.service.service_servers import Server, needs_recon, wait_job
from tests.service.small_disks import fill, tmpfs
from tests.waits import HANG_S

pytestmark = [pytest.mark.timeout(600), pytest.mark.long(50)]

MiB = 2**20


def _result_job(c, shape=(64, 16, 16), seed: int = 1) -> str:
    """A succeeded NER reconstruction of a random dataset; its id. Its volume has ``shape``: n_t
    rows of c·dt (30 µm at the default 1500 m/s) asked for, not the default depth grid."""
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(seed).standard_normal(shape).astype(np.float32))
    r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
               files={"file": (f"d{seed}.npy", buf.getvalue())})
    assert r.status_code == 201, r.text
    r = c.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "ner",
                                              "params": {"n_z": shape[0], "dz": "30um"}})
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


@needs_recon
def test_a_full_disk_answers_every_export_507_and_leaves_no_temporary(tmp_path, small_disk):
    srv = Server(small_disk / "data", env={"FPSCAN_DISK_RESERVE_BYTES": str(2 * MiB)})
    srv.log = tmp_path / "server.log"  # not on the disk that fills
    srv.start()
    try:
        with srv.client() as c:
            jid = _result_job(c, shape=(512, 48, 48))  # a 4.5 MiB volume
            folder = _result_folder(small_disk / "data", jid)
            fill(small_disk, leave=512 * 1024)  # room for the files' headers, not for their data
            for fmt in ("ome-tiff", "ome-zarr", "npz", "mat"):
                r = c.get(f"/api/jobs/{jid}/export/{fmt}")
                assert r.status_code == 507, (fmt, r.status_code, r.text)
                assert "no room" in r.json()["detail"] and "bytes free" in r.json()["detail"], r.text
            assert _temporaries(small_disk / "data") == []
            assert sorted(p.name for p in folder.iterdir() if p.name.startswith("volume")) == ["volume.h5"]
            log = srv.log.read_text()
            full = [line for line in log.splitlines() if f"of job {jid}: the disk is full" in line]
            print("\n".join(full))
            assert len(full) == 4 and all("OSError" in line for line in full), full
            assert "internal error" not in log
            os.unlink(small_disk / "filler.bin")
            r = c.get(f"/api/jobs/{jid}/export/ome-tiff")  # room again: exported
            assert r.status_code == 200 and len(r.content) > 512 * 48 * 48 * 4, r.status_code
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
