"""/api/health's disk usage from counters (``fpscan.service.storage.usage.DiskUsage``) on
a real folder, checked against the service's own walk (``fpscan.service.jobs.lifecycle.disk_usage``):
an answer never walks the folder (files written behind the counters' back show only after
the next checking walk), what a writer counts shows at once, a growing file's size is read
live, a checking walk corrects a counter that drifted and keeps the changes made while it
ran, and the lifecycle's deletions take their bytes off."""
from __future__ import annotations

import logging

from fpscan.service.jobs.lifecycle import delete_dataset, disk_usage
from fpscan.service.jobs.store import JobStore
from fpscan.service.storage.usage import DiskUsage

PARTS = ("scans", "results", "datasets", "exports", "other")


def _parts(answer: dict) -> dict:
    return {p: answer[f"{p}_bytes"] for p in PARTS}


def test_answers_come_from_counters_not_walks(tmp_path):
    data = tmp_path / "data"
    for part in ("datasets", "results", "scans"):
        (data / part).mkdir(parents=True)
    (data / "datasets" / "d1").mkdir()
    (data / "datasets" / "d1" / "dataset.h5").write_bytes(b"x" * 4096)
    usage = DiskUsage(data)
    usage.reconcile(disk_usage)
    assert _parts(usage.snapshot()) == _parts(disk_usage(data))
    # 2000 files behind the counters' back: no answer walks to find them
    many = data / "results" / "r1.1"
    many.mkdir()
    for i in range(2000):
        (many / f"f{i}").write_bytes(b"y" * 10)
    assert usage.snapshot()["results_bytes"] == 0
    # a writer that counts what it wrote: shown in the next answer
    usage.add_path(many)
    assert usage.snapshot()["results_bytes"] == 20000
    # a growing file: its size now (within the live part's reuse time)
    scan = data / "scans" / "s1.h5"
    scan.write_bytes(b"")
    usage.growing(scan)
    with open(scan, "ab") as f:
        f.write(b"z" * 8192)
    usage._live = None  # the live part is reused for up to LIVE_TTL_S: read it now
    assert usage.snapshot()["scans_bytes"] == 8192
    usage.grown(scan)
    with open(scan, "ab") as f:
        f.write(b"z" * 100)  # no longer growing: counted once, at the end
    usage._live = None
    assert usage.snapshot()["scans_bytes"] == 8192
    assert _parts(usage.reconcile(disk_usage)) == _parts(usage.snapshot())
    assert usage.snapshot()["scans_bytes"] == 8292


def test_a_checking_walk_corrects_drift_and_keeps_changes_made_while_it_ran(tmp_path, caplog):
    data = tmp_path / "data"
    (data / "exports").mkdir(parents=True)
    usage = DiskUsage(data)
    usage.reconcile(disk_usage)
    usage.add("exports", 5 << 20)  # a counter gone wrong (nothing was written)
    with caplog.at_level(logging.WARNING, logger="fpscan.disk"):
        usage.reconcile(disk_usage)
    assert usage.snapshot()["exports_bytes"] == 0
    assert any("exports" in r.getMessage() and "corrected" in r.getMessage() for r in caplog.records)

    def walk_while_a_file_is_stored(path):
        answer = disk_usage(path)  # the walk has passed exports/ when the file comes
        (data / "exports" / "late.h5").write_bytes(b"e" * 3000)
        usage.add_path(data / "exports" / "late.h5")
        return answer

    usage.reconcile(walk_while_a_file_is_stored)
    assert usage.snapshot()["exports_bytes"] == 3000


def test_deleting_a_dataset_takes_its_bytes_off(tmp_path):
    from fpscan.service.storage.usage import usage_for

    data = tmp_path / "data"
    store = JobStore(data / "jobs.sqlite", reserve_bytes=0)
    try:
        folder = data / "datasets" / "abc"
        folder.mkdir(parents=True)
        (folder / "dataset.h5").write_bytes(b"d" * 7000)
        store.put_dataset("abc", {"layout": "grid", "shape": [2, 2], "path": "dataset.h5"})
        usage = usage_for(data, data / "jobs.sqlite")
        usage.reconcile(disk_usage)
        assert usage.snapshot()["datasets_bytes"] == 7000
        assert delete_dataset(store, data, "abc")["bytes_freed"] == 7000
        assert usage.snapshot()["datasets_bytes"] == 0
        usage._live = None  # the database grew since the last answer's live part
        assert _parts(usage.snapshot()) == _parts(disk_usage(data))  # the database's files: stat-ed live
    finally:
        store.close()
