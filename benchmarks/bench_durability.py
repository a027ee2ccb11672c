"""Durability benchmark: what "acknowledged means on disk" costs per acknowledged upload.

An upload is acknowledged (201) after its dataset file, its folder and ``datasets/`` are
flushed (``fpscan.service.disk.fsync_tree``) and the job store's commit is durable (SQLite
WAL, ``synchronous=FULL``). This measures, in one run, on the disk of ``--dir``:

1. the storing steps of one upload, ``--uploads`` times, each way in turn (ABAB):
   *durable* -- write the ``--mib`` MiB dataset file, fsync it and its folder, rename the folder
   into ``datasets/``, fsync that, record the row (``JobStore.put_dataset``, FULL); *as before*
   -- write, rename, record with ``synchronous=NORMAL``, no fsync. Median ms of each, their
   ratio and the difference (the durability's cost per upload);
2. ``--commits`` commits of a job's state (``JobStore.set_state``, durable: FULL) and of its
   progress (``JobStore.update_progress``, a report: NORMAL), and the state's commits with the
   store set back to NORMAL (as before): median ms each and the ratio of the first to the last;
3. a real upload of a ``--mib`` MiB ``.npy`` through ``fpscan serve`` (127.0.0.1), ``--uploads``
   times: the median ms a client waits for its 201, and the durability's share of it.

Run: ``.venv/bin/python benchmarks/bench_durability.py`` (``--quick``: fewer repetitions).
Prints one JSON object.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import statistics
import subprocess
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import numpy as np

from fpscan.clients.processes import start_service
from fpscan.service.disk import fsync_folder, fsync_tree
from fpscan.service.jobs.store import JobStore

TOKEN = "bench-token"


def _store(folder: Path, synchronous: str) -> JobStore:
    store = JobStore(folder / "jobs.sqlite", reserve_bytes=0)
    # the benchmark's "as before" arm: the store's own connection set back to NORMAL
    store._db.execute(f"PRAGMA synchronous={synchronous}")
    return store


def _one_upload(root: Path, store: JobStore, payload: bytes, durable: bool) -> float:
    dataset_id = uuid.uuid4().hex
    t0 = time.perf_counter()
    dest = root / "incoming" / dataset_id
    dest.mkdir(parents=True)
    (dest / "dataset.h5").write_bytes(payload)
    if durable:
        fsync_tree(dest, parent=False)
    stored = root / "datasets" / dataset_id
    stored.parent.mkdir(exist_ok=True)
    dest.rename(stored)
    if durable:
        fsync_folder(stored.parent)
    store.put_dataset(dataset_id, {"path": "dataset.h5", "layout": "grid"})
    return time.perf_counter() - t0


def storing(root: Path, mib: float, uploads: int) -> dict:
    payload = np.random.default_rng(1).bytes(int(mib * 2**20))
    arms = {"durable": (root / "durable", "FULL", True), "as_before": (root / "before", "NORMAL", False)}
    stores = {k: _store(folder, sync) for k, (folder, sync, _) in arms.items()}
    times: dict[str, list[float]] = {k: [] for k in arms}
    try:
        for _ in range(uploads):
            for k, (folder, _sync, durable) in arms.items():  # in turn: the disk's drift hits both
                times[k].append(_one_upload(folder, stores[k], payload, durable))
    finally:
        for s in stores.values():
            s.close()
    med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    return {"mib": mib, "uploads": uploads, "durable_ms": round(med["durable"], 3),
            "as_before_ms": round(med["as_before"], 3), "ratio": round(med["durable"] / med["as_before"], 2),
            "cost_ms_per_upload": round(med["durable"] - med["as_before"], 3)}


def commits(root: Path, n: int) -> dict:
    out = {}
    for arm, sync in (("state_full", "FULL"), ("progress_report", "FULL"), ("state_as_before", "NORMAL")):
        store = _store(root / f"commits-{arm}", sync)
        try:
            job, _ = store.create_job("recon", {})
            times = []
            for i in range(n):
                t0 = time.perf_counter()
                if arm == "progress_report":
                    store.update_progress(job["id"], {"fraction": i / n})
                else:  # a state change each time (queued <-> paused), as a control's answer records one
                    store.set_state(job["id"], "paused" if i % 2 == 0 else "queued")
                times.append(time.perf_counter() - t0)
        finally:
            store.close()
        out[arm] = statistics.median(times) * 1e3
    return {"commits": n, **{f"{k}_ms": round(v, 3) for k, v in out.items()},
            "state_ratio": round(out["state_full"] / out["state_as_before"], 2)}


def served(root: Path, mib: float, uploads: int) -> dict:
    n_t = max(1, int(mib * 2**20 / (4 * 16 * 16)))
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(2).standard_normal((n_t, 16, 16)).astype(np.float32))
    srv = start_service(root / "served", token=TOKEN, web=False,
                        env={"FPSCAN_WARM_UP": "false", "FPSCAN_RETENTION_DATASETS_KEEP_BYTES": "0"})
    try:
        times = []
        with httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=120) as c:
            for i in range(uploads + 1):
                body = buf.getvalue()[:-4] + np.float32(i).tobytes()  # new bytes: no deduplication
                t0 = time.perf_counter()
                r = c.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                           files={"file": ("d.npy", body)})
                dt = time.perf_counter() - t0
                r.raise_for_status()
                if i:  # the first warms the import worker
                    times.append(dt)
    finally:
        srv.stop()
    return {"uploads": uploads, "median_ms": round(statistics.median(times) * 1e3, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dir", default=None, help="folder on the disk to measure (default: the system's temp folder)")
    ap.add_argument("--mib", type=float, default=4.0, help="dataset size, MiB")
    ap.add_argument("--uploads", type=int, default=20)
    ap.add_argument("--commits", type=int, default=200)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    if args.quick:
        args.uploads, args.commits = 6, 50
    root = Path(tempfile.mkdtemp(prefix="fpscan-durability-", dir=args.dir))
    try:
        fs = subprocess.run(["stat", "-f", "-c", "%T", str(root)], capture_output=True, text=True).stdout.strip()
        store = storing(root, args.mib, args.uploads)
        commit = commits(root, args.commits)
        upload = served(root, args.mib, args.uploads)
        share = store["cost_ms_per_upload"] / upload["median_ms"] if upload["median_ms"] else None
        print(json.dumps({"dir": str(root), "filesystem": fs, "cpus": os.cpu_count(), "storing": store,
                          "job_state_commits": commit, "served_upload": upload,
                          "durability_share_of_upload": None if share is None else round(share, 3)}))
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
