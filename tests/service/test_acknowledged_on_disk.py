"""Acknowledged means on disk: what a 2xx (or a job's recorded success) names is flushed to
disk, file then folder, before the job store's durable commit that records it, and the
answer comes after that commit.

A real ``fpscan serve`` (and its worker processes) runs with an fsync and SQLite recorder on
its ``PYTHONPATH`` (``tests/service/fsync_shim/sitecustomize.py``: it wraps ``os.fsync`` and
``sqlite3.connect`` and writes one line per call, in order, to one file; it changes nothing).
For an upload, a plan, a scan and a reconstruction's result, the record read once the answer
(or the job's ``succeeded``) has come must show, in this order: the data file's fsync, its
folder's, the folder above's where the data's folder was renamed into it, then the statement
that records it and its commit on a connection set to ``synchronous=FULL`` (SQLite: a
commit of WAL mode survives a power cut only with FULL; the ALICE study: a rename without
the file's and the folder's fsync may be persisted before the data).
"""
from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest

from tests.service.service_servers import Server, needs_recon, wait_job

driver_sim = pytest.importorskip("fpscan.driver.simulator")

pytestmark = [needs_recon, pytest.mark.slow]

SHIM = Path(__file__).resolve().parent / "fsync_shim"


class Record:
    """The recorder's lines: ``("fsync", pid, path)`` and ``("sql", pid, connection,
    database, statement)``, in the order they happened."""

    def __init__(self, path: Path) -> None:
        self.lines: list[tuple[str, ...]] = []
        for line in path.read_text(encoding="utf-8").splitlines():
            kind, rest = line.split(" ", 1)
            if kind == "fsync":
                self.lines.append(("fsync", *rest.split(" ", 1)))
            else:
                self.lines.append(("sql", *rest.split(" ", 3)))

    def fsync(self, path: Path) -> int:
        """Where ``path`` was flushed (the first time), -1 when it never was."""
        for i, line in enumerate(self.lines):
            if line[0] == "fsync" and line[2] == str(path):
                return i
        return -1

    def statement(self, *words: str) -> int:
        """Where the first statement holding every one of ``words`` began, -1 when none did."""
        for i, line in enumerate(self.lines):
            if line[0] == "sql" and all(w in line[4] for w in words):
                return i
        return -1

    def commit_after(self, i: int) -> int:
        """Where the statement at ``i`` was committed: itself when it ran alone (autocommit:
        no ``BEGIN`` of its connection open), else its transaction's ``COMMIT``; -1 when it
        never was."""
        mine = [j for j, line in enumerate(self.lines) if line[0] == "sql" and line[1:3] == self.lines[i][1:3]
                and line[4].upper().startswith(("BEGIN", "COMMIT", "ROLLBACK"))]
        before = [j for j in mine if j < i]
        if not before or not self.lines[before[-1]][4].upper().startswith("BEGIN"):
            return i
        after = [j for j in mine if j > i]
        return after[0] if after and self.lines[after[0]][4].upper().startswith("COMMIT") else -1

    def synchronous(self, i: int) -> str | None:
        """The last ``PRAGMA synchronous`` the connection of the statement at ``i`` set."""
        pid, conn = self.lines[i][1], self.lines[i][2]
        said = None
        for line in self.lines[:i]:
            if line[0] == "sql" and line[1:3] == (pid, conn) and line[4].upper().startswith("PRAGMA SYNCHRONOUS"):
                said = line[4].split("=", 1)[-1].strip().upper()
        return said


def _ordered(record: Record, steps: list[tuple[str, int]]) -> None:
    """Each step happened, in the order given."""
    assert all(i >= 0 for _, i in steps), steps
    assert [i for _, i in steps] == sorted(i for _, i in steps), steps


def npy_bytes() -> bytes:
    buf = io.BytesIO()
    rng = np.random.default_rng(7)
    np.save(buf, rng.standard_normal((128, 12, 12)).astype(np.float32))
    return buf.getvalue()


@pytest.fixture
def sim():
    s = driver_sim.SimulatedScanner(prf=200.0, seed=3).start()
    yield s
    s.stop()


def test_upload_plan_scan_and_result_are_on_disk_before_their_commit_and_answer(tmp_path, sim):
    record_path = tmp_path / "record.txt"
    path = os.pathsep.join([str(SHIM), *filter(None, [os.environ.get("PYTHONPATH")])])
    data = (tmp_path / "srv").resolve()
    srv = Server(data, devices={"sim": sim.path},
                 env={"PYTHONPATH": path, "FSYNC_RECORD": str(record_path)}).start()
    try:
        with srv.client() as c:
            # an upload: dataset file -> its folder -> datasets/ -> the row's commit -> 201
            r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                       files={"file": ("d.npy", npy_bytes())})
            assert r.status_code == 201, r.text
            did = r.json()["dataset_id"]
            rec = Record(record_path)  # read once the 201 is here: what it shows came before it
            row = rec.statement("INSERT INTO datasets", did)
            _ordered(rec, [("file", rec.fsync(data / "incoming" / did / "dataset.h5")),
                           ("folder", rec.fsync(data / "incoming" / did)),
                           ("datasets/", rec.fsync(data / "datasets")),
                           ("insert", row), ("commit", rec.commit_after(row))])
            assert rec.synchronous(row) == "FULL"
            print(f"upload: {len(rec.lines)} records")

            # a plan (the job store holds it): its commit -> 201
            r = c.post("/api/plans", json={"lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4},
                                           "points": [[i, j] for j in range(4) for i in range(4)],
                                           "acquisition": {"n_t": 64, "dt": 2e-8, "prf": 200}})
            assert r.status_code == 201, r.text
            pid = r.json()["id"]
            rec = Record(record_path)
            row = rec.statement("INTO plans", pid)
            _ordered(rec, [("insert", row), ("commit", rec.commit_after(row))])
            assert rec.synchronous(row) == "FULL"

            # a scan: its file -> scans/ -> the succeeded state's commit -> the job reads succeeded
            r = c.post("/api/scans", json={"plan_id": pid, "scanner_id": "sim"})
            assert r.status_code == 202, r.text
            sid = r.json()["id"]
            assert wait_job(c, sid)["state"] == "succeeded"
            rec = Record(record_path)
            done = rec.statement("UPDATE jobs", "'succeeded'", sid)
            _ordered(rec, [("file", rec.fsync(data / "scans" / f"{sid}.h5")), ("scans/", rec.fsync(data / "scans")),
                           ("update", done), ("commit", rec.commit_after(done))])
            assert rec.synchronous(done) == "FULL"

            # a result: its files -> its folder -> results/ -> the succeeded state's commit
            r = c.post("/api/reconstructions", json={"dataset_id": did, "method": "ner"})
            assert r.status_code == 202, r.text
            jid = r.json()["id"]
            job = wait_job(c, jid)
            assert job["state"] == "succeeded", job
            rec = Record(record_path)
            done = rec.statement("UPDATE jobs", "'succeeded'", jid)
            folder = next((data / "results").glob(f"{jid}.*"))
            files = [rec.fsync(p) for p in sorted(folder.iterdir())]
            assert len(files) >= 2 and min(files) >= 0, files  # volume.h5 and the MIP pictures
            _ordered(rec, [("files", max(files)), ("folder", rec.fsync(folder)),
                           ("results/", rec.fsync(data / "results")),
                           ("update", done), ("commit", rec.commit_after(done))])
            assert rec.synchronous(done) == "FULL"
    finally:
        srv.stop()
