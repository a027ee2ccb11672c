"""Data lifecycle of the store: deleting plans, jobs (with their files) and datasets,
the retention policy, and the disk use of the data folder.

The rules, one place for the API, the queue and the tests:

- Nothing a queued, running or paused job may still read is deleted: a job itself while
  it is active, the scan file of a scan job that an active reconstruction reads, the plan
  of an active scan, a dataset an active reconstruction reads. Such a request raises
  :class:`InUse` (HTTP 409) naming the job that holds it.
- Deleting a job removes its database row and events and its files: a scan job's scan
  file and exports, a reconstruction's result folder(s) (every attempt).
- Retention (:func:`apply_retention`): keep the newest ``keep_results`` finished
  reconstructions and/or at most ``keep_bytes`` bytes of result files; the oldest
  finished go first, whole (row and files). Scan files are never removed by retention
  unless ``include_scans`` is set (then finished scans count towards ``keep_bytes`` and
  are removed oldest first too, never one an active job reads). The policy is stored in
  the job database (``config`` table), so a restart keeps it; the service settings
  (``retention_keep_results``, ``retention_keep_bytes``, ``retention_include_scans``)
  give the policy until one is set through ``PUT /api/retention``.
- Dataset retention (same policy): uploaded datasets no active job reads are removed
  oldest first when not used (uploaded, or uploaded again) for ``datasets_max_age_s`` or beyond ``datasets_keep_bytes``
  bytes of dataset files (settings ``retention_datasets_keep_bytes``,
  ``retention_datasets_max_age_s``); a dataset a queued, running or paused job reads is
  never removed.

Acknowledged means stored: deleting and acknowledging a reference are
serialised (:func:`guard`, one lock per store): a deletion checks its users and removes
the row under it, and whatever answers with a plan, job or dataset that must go on
existing (a job created on its inputs, a dataset an upload is answered with) checks and
records it under it too. A dataset an upload is answered with is also *held*
(:func:`hold_dataset`) until that answer has been sent: a deletion of it waits for the
release (:data:`HOLD_WAIT_S` at most, then :class:`InUse`), and retention passes it by.
So a 201 names a dataset that exists when it is sent, and a deletion that raced it came
first (the upload then stored or found another) or comes after it.

Layout of the data folder (``settings.data_dir``): ``scans/<job>.h5``,
``exports/<job><suffix>`` (a scan's exports: ``_ipasc.h5``, ...), ``results/<job>.<attempt>/``,
``datasets/<id>/``, ``jobs.sqlite``.
"""
from __future__ import annotations

import contextlib
import logging
import os
import shutil
import threading
import time
import weakref
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import Any

from fpscan.service.disk import free_bytes
from fpscan.service.jobs.store import ACTIVE, JobStore
from fpscan.service.storage.usage import tree_bytes, usage_for

__all__ = [
    "RETENTION_KEY", "HOLD_WAIT_S", "HOLD_STALE_S", "InUse", "NotFound", "guard", "hold_dataset",
    "release_dataset", "create_job", "job_files", "job_dataset_ids", "delete_job", "delete_plan",
    "delete_dataset", "list_datasets", "apply_dataset_retention", "default_retention", "get_retention",
    "set_retention", "apply_retention", "DISK_PARTS", "DISK_WALK_STEP", "disk_usage", "disk_usage_steps",
]

log = logging.getLogger("fpscan.lifecycle")

RETENTION_KEY = "retention"


class InUse(ValueError):
    """The thing to delete is used by an active job (HTTP 409).

    A ``ValueError``.

    Attributes
    ----------
    args : tuple
        The message, naming the job that holds it.
    """


class NotFound(KeyError):
    """No such plan, job or dataset (HTTP 404).

    A ``KeyError`` whose ``str`` is its message unquoted.

    Attributes
    ----------
    args : tuple
        The message (``"no job <id>"``, ...).
    """

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else "not found"


#: longest a deletion waits for the answer of an upload that holds its dataset, s
HOLD_WAIT_S = 10.0
#: a hold older than this is dropped (its answer was never sent: a release that never came), s
HOLD_STALE_S = 60.0


class _References:
    """One store's lock for deleting and acknowledging, and the datasets held by answers
    being sent (id -> the ``time.monotonic()`` of each hold)."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.released = threading.Condition(self.lock)
        self.holds: dict[str, list[float]] = {}

    def held(self, dataset_id: str) -> bool:
        now = time.monotonic()
        fresh = [t for t in self.holds.get(dataset_id, []) if now - t < HOLD_STALE_S]
        if fresh:
            self.holds[dataset_id] = fresh
        else:
            self.holds.pop(dataset_id, None)
        return bool(fresh)


_REFERENCES: weakref.WeakKeyDictionary[JobStore, _References] = weakref.WeakKeyDictionary()
_REFERENCES_LOCK = threading.Lock()


def _refs(store: JobStore) -> _References:
    with _REFERENCES_LOCK:
        refs = _REFERENCES.get(store)
        if refs is None:
            refs = _REFERENCES[store] = _References()
        return refs


@contextlib.contextmanager
def guard(store: JobStore) -> Iterator[None]:
    """Hold off every deletion of ``store``'s plans, jobs and datasets for the block: check
    a reference and acknowledge it inside (re-entrant; keep it short: no file is written
    under it but a rename).

    Parameters
    ----------
    store : JobStore
        The job store (one lock per store object).

    Yields
    ------
    None
    """
    with _refs(store).lock:
        yield


def hold_dataset(store: JobStore, dataset_id: str) -> None:
    """Keep ``dataset_id`` from deletion until :func:`release_dataset` (an upload's answer
    naming it is being sent; call it under :func:`guard`, where the dataset was found).
    Holds count; one older than :data:`HOLD_STALE_S` is dropped.

    Parameters
    ----------
    store : JobStore
        The job store.
    dataset_id : str
        The dataset.
    """
    refs = _refs(store)
    with refs.lock:
        refs.holds.setdefault(dataset_id, []).append(time.monotonic())


def release_dataset(store: JobStore, dataset_id: str) -> None:
    """Release one hold of :func:`hold_dataset` (the answer was sent, or failed); a
    deletion waiting for it goes on.

    Parameters
    ----------
    store : JobStore
        The job store.
    dataset_id : str
        The dataset.
    """
    refs = _refs(store)
    with refs.lock:
        held = refs.holds.get(dataset_id)
        if held:
            held.pop(0)
            if not held:
                del refs.holds[dataset_id]
        refs.released.notify_all()


def create_job(store: JobStore, kind: str, params: dict, **kwargs: Any) -> tuple[dict, bool]:
    """Create a job whose inputs exist, under :func:`guard`: its datasets
    (:func:`job_dataset_ids`), its scan job (``params["scan_job_id"]``) and its plan
    (``params["plan_id"]`` of a scan) are looked up and the job created in one step, so no
    deletion falls between them (and a deletion after it sees the job among the users).

    Parameters
    ----------
    store : JobStore
        The job store.
    kind : {"scan", "recon"}
        The job's kind.
    params : dict
        Its parameters, as stored.
    **kwargs
        ``JobStore.create_job``'s options (``idempotency_key``, ``memory_bytes``, ...).

    Returns
    -------
    tuple of (dict, bool)
        ``JobStore.create_job``'s ``(job, created)``.

    Raises
    ------
    NotFound
        An input is gone (deleted since the request was checked).
    fpscan.service.jobs.store.IdempotencyConflict
        As ``JobStore.create_job``.
    """
    with guard(store):
        for dataset_id in sorted(job_dataset_ids({"kind": kind, "params": params})):
            if store.get_dataset(dataset_id) is None:
                raise NotFound(f"no dataset {dataset_id}")
        if kind == "recon" and params.get("scan_job_id") and store.get(params["scan_job_id"]) is None:
            raise NotFound(f"no scan job {params['scan_job_id']}")
        if kind == "scan" and params.get("plan_id") and store.get_plan_summary(params["plan_id"]) is None:
            raise NotFound(f"no plan {params['plan_id']}")
        return store.create_job(kind, params, **kwargs)


def _tree_bytes(path: Path) -> int:
    """Bytes of the files under ``path`` (a file or a folder; 0 if missing)."""
    return tree_bytes(path)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def job_files(job: dict, data_dir: str | os.PathLike) -> list[Path]:
    """The files and folders that belong to ``job`` (existing ones only).

    A scan job's scan file and its exports (``exports/<job><suffix>``); a reconstruction's
    result folder(s) of every attempt (its exports inside) and their progress files.

    Parameters
    ----------
    job : dict
        A job row of the store (``id``, ``kind``, ``params``, ``result_path``).
    data_dir : str or os.PathLike
        The data folder (``settings.data_dir``).

    Returns
    -------
    list of pathlib.Path
        The existing paths, each once.
    """
    data = Path(data_dir)
    jid = job["id"]
    out: list[Path] = []
    if job["kind"] == "scan":
        scan_path = job["params"].get("scan_path")
        if scan_path:
            out.append(Path(scan_path))
        out.append(data / "scans" / f"{jid}.h5")
        exports = data / "exports"
        if exports.is_dir():  # every export written of it (<job><suffix>: _ipasc.h5, .h5, ...)
            out += [p for p in exports.iterdir() if p.name.startswith((f"{jid}.", f"{jid}_"))]
    else:
        if job.get("result_path"):
            out.append(Path(job["result_path"]))
        results = data / "results"
        if results.is_dir():  # every attempt's folder and progress file
            out += [p for p in results.iterdir()
                    if p.name.startswith(f"{jid}.") or p.name.startswith(f".{jid}.")]
    seen: set[Path] = set()
    unique = []
    for p in out:
        if p not in seen and (p.exists() or p.is_symlink()):
            seen.add(p)
            unique.append(p)
    return unique


def job_dataset_ids(job: dict) -> set[str]:
    """The uploaded datasets a reconstruction job reads.

    Parameters
    ----------
    job : dict
        A job row of the store (``kind``, ``params``).

    Returns
    -------
    set of str
        Its ``dataset_id``, or the datasets of an unmixing job (``input_id``
        ``datasets:<id>,<id>...``); empty for a scan job.
    """
    if job.get("kind") != "recon":
        return set()
    p = job["params"]
    out = {p["dataset_id"]} if p.get("dataset_id") else set()
    input_id = str(p.get("input_id") or "")
    if input_id.startswith("datasets:"):
        out |= {d for d in input_id.removeprefix("datasets:").split(",") if d}
    return out


def _users(store: JobStore, *, scan_job: str | None = None, plan: str | None = None,
           dataset: str | None = None) -> list[dict]:
    """Active jobs that read the given scan job's file, plan or dataset."""
    found = []
    for job in store.active_jobs():
        p = job["params"]
        if scan_job is not None and job["kind"] == "recon" and p.get("scan_job_id") == scan_job:
            found.append(job)
        elif plan is not None and job["kind"] == "scan" and p.get("plan_id") == plan:
            found.append(job)
        elif dataset is not None and dataset in job_dataset_ids(job):
            found.append(job)
    return found


def delete_job(store: JobStore, data_dir: str | os.PathLike, job_id: str) -> dict:
    """Delete a finished job, its events and its files.

    Parameters
    ----------
    store : JobStore
        The job store.
    data_dir : str or os.PathLike
        The data folder (``settings.data_dir``).
    job_id : str
        The job.

    Returns
    -------
    dict
        ``{"id", "kind", "bytes_freed"}``.

    Raises
    ------
    NotFound
        If there is no such job.
    InUse
        If the job is active, or an active reconstruction reads this scan.
    """
    with guard(store):  # no reconstruction of this scan is created between the check and the deletion
        job = store.get(job_id)
        if job is None:
            raise NotFound(f"no job {job_id}")
        if job["state"] in ACTIVE:
            raise InUse(f"job {job_id} is {job['state']}: cancel it first")
        users = _users(store, scan_job=job_id) if job["kind"] == "scan" else []
        if users:
            raise InUse(f"scan job {job_id} is read by {users[0]['state']} reconstruction {users[0]['id']}")
        files = job_files(job, data_dir)
        sizes = [_tree_bytes(p) for p in files]
        freed = sum(sizes)
        if not store.delete_job(job_id):  # it became active again (resumed) in the meantime
            raise InUse(f"job {job_id} is active: cancel it first")
    usage = usage_for(data_dir)
    for p, n in zip(files, sizes, strict=True):
        _remove(p)
        usage.add_path(p, removed=True, nbytes=n)  # /api/health's counters
    log.info("deleted job=%s kind=%s bytes=%d", job_id, job["kind"], freed)
    return {"id": job_id, "kind": job["kind"], "bytes_freed": freed}


def delete_plan(store: JobStore, plan_id: str) -> dict:
    """Delete a stored plan.

    Parameters
    ----------
    store : JobStore
        The job store.
    plan_id : str
        The plan.

    Returns
    -------
    dict
        ``{"id", "bytes_freed"}`` (``bytes_freed`` 0: a plan has no files).

    Raises
    ------
    NotFound
        If there is no such plan.
    InUse
        If an active scan uses it.
    """
    with guard(store):  # no scan of this plan is created between the check and the deletion
        if store.get_plan_summary(plan_id) is None:
            raise NotFound(f"no plan {plan_id}")
        users = _users(store, plan=plan_id)
        if users:
            raise InUse(f"plan {plan_id} is used by {users[0]['state']} scan job {users[0]['id']}")
        store.delete_plan(plan_id)
    return {"id": plan_id, "bytes_freed": 0}


def delete_dataset(store: JobStore, data_dir: str | os.PathLike, dataset_id: str, *,
                   wait_s: float = HOLD_WAIT_S) -> dict:
    """Delete an uploaded dataset and its folder.

    Under :func:`guard`: a dataset held by an upload's answer (:func:`hold_dataset`) is
    deleted once that answer has been sent (waiting ``wait_s`` at most), so an upload
    answered with it is never answered with a dataset already gone.

    Parameters
    ----------
    store : JobStore
        The job store.
    data_dir : str or os.PathLike
        The data folder (``settings.data_dir``).
    dataset_id : str
        The dataset.
    wait_s : float, optional
        Longest wait for a hold's release, s; default :data:`HOLD_WAIT_S` (0: none, as
        retention does).

    Returns
    -------
    dict
        ``{"id", "bytes_freed"}``.

    Raises
    ------
    NotFound
        If there is no such dataset.
    InUse
        If an active reconstruction reads it, or an upload's answer still holds it after
        ``wait_s``.
    """
    refs = _refs(store)
    deadline = time.monotonic() + wait_s
    with refs.lock:
        while True:
            if store.get_dataset(dataset_id) is None:
                raise NotFound(f"no dataset {dataset_id}")
            users = _users(store, dataset=dataset_id)
            if users:
                raise InUse(f"dataset {dataset_id} is read by {users[0]['state']} reconstruction {users[0]['id']}")
            left = deadline - time.monotonic()
            if not refs.held(dataset_id):
                break
            if left <= 0:
                raise InUse(f"dataset {dataset_id} was just given to an upload (deduplicated), whose answer is "
                            "still being sent; retry")
            refs.released.wait(min(left, 1.0))
        store.delete_dataset(dataset_id)
    folder = Path(data_dir) / "datasets" / dataset_id
    freed = _tree_bytes(folder)
    _remove(folder)
    usage_for(data_dir).add_path(folder, removed=True, nbytes=freed)  # /api/health's counters
    log.info("deleted dataset=%s bytes=%d", dataset_id, freed)
    return {"id": dataset_id, "bytes_freed": freed}


def list_datasets(store: JobStore, data_dir: str | os.PathLike) -> list[dict]:
    """Every uploaded dataset, oldest first.

    Parameters
    ----------
    store : JobStore
        The job store.
    data_dir : str or os.PathLike
        The data folder (``settings.data_dir``).

    Returns
    -------
    list of dict
        ``{"dataset_id", "name", "format", "layout", "shape", "dt", "wavelength_nm",
        "wavelength_index", "content_sha256", "size_bytes" (its files on disk), "created"
        (UNIX s), "last_used" (UNIX s: the upload, or the latest identical upload answered
        with it), "jobs" (ids of the jobs that read it, any state), "in_use" (a queued,
        running or paused one does)}``.
    """
    return [listed for listed, _ in _datasets(store, data_dir)]


def _datasets(store: JobStore, data_dir: str | os.PathLike) -> list[tuple[dict, float]]:
    """:func:`list_datasets`' rows, each with the store time of its upload or latest use (s)."""
    users: dict[str, list[str]] = {}
    active: set[str] = set()
    for job in store.list(kind="recon", limit=1_000_000):
        for ds in job_dataset_ids(job):
            users.setdefault(ds, []).append(job["id"])
            if job["state"] in ACTIVE:
                active.add(ds)
    out: list[tuple[dict, float]] = []
    for row in store.list_datasets():
        meta, did = row["meta"], row["id"]
        out.append(({"dataset_id": did, "name": meta.get("name"), "format": meta.get("format"),
                     "layout": meta.get("layout"), "shape": meta.get("shape"), "dt": meta.get("dt"),
                     "wavelength_nm": meta.get("wavelength_nm"), "wavelength_index": meta.get("wavelength_index"),
                     "content_sha256": meta.get("content_sha256"),
                     "size_bytes": _tree_bytes(Path(data_dir) / "datasets" / did), "created": row["created"],
                     "last_used": max(float(meta.get("last_used") or 0.0), row["created"]),
                     "jobs": users.get(did, []), "in_use": did in active}, float(row["used_mono"])))
    return out


def apply_dataset_retention(store: JobStore, settings: Any, policy: dict | None = None,
                            now: float | None = None) -> list[str]:
    """Delete uploaded datasets beyond the retention policy's dataset part.

    A dataset not used (uploaded, or uploaded again) for longer than ``datasets_max_age_s``
    goes; then, beyond ``datasets_keep_bytes``, the least recently used go first (used:
    uploaded, or uploaded again and answered by deduplication) until the rest fit; the most
    recently used is never removed for its bytes. A dataset an active job reads is kept (and
    still counts towards the bytes). Ages and the order of use are on the store's time
    (``JobStore.monotonic``, :mod:`fpscan.service.jobs.store.clock`), not the wall clock: a
    clock set forward by ``datasets_max_age_s`` deletes nothing.

    Parameters
    ----------
    store : JobStore
        The job store.
    settings : fpscan.service.settings.Settings
        The service settings: ``data_dir`` and the ``retention_*`` defaults.
    policy : dict or None, optional
        The policy (:func:`get_retention`'s dict); default None: the one in force.
    now : float or None, optional
        The store's time now, s; default None: ``store.monotonic()``.

    Returns
    -------
    list of str
        The deleted datasets' ids.
    """
    policy = policy or get_retention(store, settings)
    max_age, keep_bytes = policy.get("datasets_max_age_s"), policy.get("datasets_keep_bytes")
    if max_age is None and keep_bytes is None:
        return []
    now = store.monotonic() if now is None else now
    listed = sorted(_datasets(store, settings.data_dir), key=lambda pair: pair[1])  # stable: as stored on ties
    rows = [r for r, _ in listed]
    victims: list[str] = []
    total = sum(r["size_bytes"] for r in rows)
    for i, (r, used) in enumerate(listed):  # least recently used first
        if r["in_use"]:
            continue
        too_old = max_age is not None and now - used > max_age
        # the most recently used is kept for the bytes: it was just uploaded (or asked for
        # again), to be reconstructed
        too_much = keep_bytes is not None and total > keep_bytes and i < len(rows) - 1
        if too_old or too_much:
            victims.append(r["dataset_id"])
            total -= r["size_bytes"]
    deleted = []
    for did in victims:
        try:  # one an upload's answer holds is kept (it was just asked for)
            delete_dataset(store, settings.data_dir, did, wait_s=0.0)
            deleted.append(did)
        except (InUse, NotFound) as exc:
            log.info("retention kept dataset=%s: %s", did, exc)
    if deleted:
        log.info("retention deleted datasets=%s policy=%s", deleted, policy)
    return deleted


# -- retention --------------------------------------------------------------------------
def default_retention(settings: Any) -> dict:
    """The retention policy the service settings give (``retention_*``).

    Parameters
    ----------
    settings : fpscan.service.settings.Settings
        The service settings (a missing ``retention_*`` attribute counts as no limit).

    Returns
    -------
    dict
        ``{"keep_results", "keep_bytes", "include_scans", "datasets_keep_bytes",
        "datasets_max_age_s"}``; None = no limit.
    """
    return {"keep_results": getattr(settings, "retention_keep_results", None),
            "keep_bytes": getattr(settings, "retention_keep_bytes", None),
            "include_scans": bool(getattr(settings, "retention_include_scans", False)),
            "datasets_keep_bytes": getattr(settings, "retention_datasets_keep_bytes", None),
            "datasets_max_age_s": getattr(settings, "retention_datasets_max_age_s", None)}


def get_retention(store: JobStore, settings: Any) -> dict:
    """The retention policy in force: the stored one, else the settings'.

    Parameters
    ----------
    store : JobStore
        The job store.
    settings : fpscan.service.settings.Settings
        The service settings (:func:`default_retention`; they fill keys the stored policy lacks).

    Returns
    -------
    dict
        The policy, as :func:`default_retention` gives it.
    """
    stored = store.get_config(RETENTION_KEY)
    return {**default_retention(settings), **stored} if isinstance(stored, dict) else \
        default_retention(settings)


def set_retention(store: JobStore, policy: dict) -> dict:
    """Store a retention policy (it survives restarts).

    Parameters
    ----------
    store : JobStore
        The job store.
    policy : dict
        ``{"keep_results": int|None, "keep_bytes": int|None, "include_scans": bool,
        "datasets_keep_bytes": int|None, "datasets_max_age_s": float|None}``; missing keys
        are None (``include_scans`` False), other keys are dropped.

    Returns
    -------
    dict
        The policy as stored.

    Raises
    ------
    ValueError
        If a count or byte limit is not a whole number >= 0 or None, or
        ``datasets_max_age_s`` is not a finite number of seconds >= 0 or None.
    """
    out = {"keep_results": policy.get("keep_results"), "keep_bytes": policy.get("keep_bytes"),
           "include_scans": bool(policy.get("include_scans", False)),
           "datasets_keep_bytes": policy.get("datasets_keep_bytes"),
           "datasets_max_age_s": policy.get("datasets_max_age_s")}
    for key in ("keep_results", "keep_bytes", "datasets_keep_bytes"):
        v = out[key]
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 0):
            raise ValueError(f"{key} must be a whole number >= 0 or null, got {v!r}")
    age = out["datasets_max_age_s"]
    if age is not None and (isinstance(age, bool) or not isinstance(age, (int, float)) or not age >= 0
                            or age == float("inf")):
        raise ValueError(f"datasets_max_age_s must be a number of seconds >= 0 or null, got {age!r}")
    store.set_config(RETENTION_KEY, out)
    return out


def apply_retention(store: JobStore, settings: Any) -> list[str]:
    """Delete the oldest finished jobs beyond the retention policy, and the datasets beyond it.

    The datasets go first (:func:`apply_dataset_retention`). Candidate jobs: finished
    reconstructions that have result files (and, with ``include_scans``, finished scans with
    a scan file that no active job reads), oldest finished first. ``keep_results`` keeps the
    newest N reconstruction results; ``keep_bytes`` then removes the oldest candidates until
    their files fit. A job that became active or vanished meanwhile is kept (logged).

    Parameters
    ----------
    store : JobStore
        The job store.
    settings : fpscan.service.settings.Settings
        The service settings: ``data_dir`` and the ``retention_*`` defaults.

    Returns
    -------
    list of str
        The ids of the deleted datasets, then of the deleted jobs.
    """
    policy = get_retention(store, settings)
    datasets = apply_dataset_retention(store, settings, policy)
    keep_n, keep_bytes = policy["keep_results"], policy["keep_bytes"]
    if keep_n is None and keep_bytes is None:
        return datasets
    data_dir = settings.data_dir
    recon = [j for j in store.finished_jobs("recon") if job_files(j, data_dir)]
    victims: list[dict] = []
    if keep_n is not None and len(recon) > keep_n:
        victims += recon[:len(recon) - keep_n]
    if keep_bytes is not None:
        pool = [j for j in recon if j not in victims]
        if policy["include_scans"]:
            busy = {j["params"].get("scan_job_id") for j in store.active_jobs()}
            pool += [j for j in store.finished_jobs("scan")
                     if j["id"] not in busy and job_files(j, data_dir)]
            pool.sort(key=lambda j: (j["finished_mono"] or 0.0, j["seq"] or 0))  # oldest finished first
        sizes = {j["id"]: sum(_tree_bytes(p) for p in job_files(j, data_dir)) for j in pool}
        total = sum(sizes.values())
        for j in pool:
            if total <= keep_bytes:
                break
            victims.append(j)
            total -= sizes[j["id"]]
    deleted = []
    for j in victims:
        try:
            delete_job(store, data_dir, j["id"])
            deleted.append(j["id"])
        except (InUse, NotFound) as exc:
            log.info("retention kept job=%s: %s", j["id"], exc)
    if deleted:
        log.info("retention deleted jobs=%s policy=%s", deleted, policy)
    return datasets + deleted


# -- disk use ---------------------------------------------------------------------------
#: parts of the data folder that disk_usage counts apart (the rest is ``other_bytes``)
DISK_PARTS = ("scans", "results", "datasets", "exports")
#: entries disk_usage_steps looks at between two of its yields
DISK_WALK_STEP = 256


def disk_usage(data_dir: str | os.PathLike) -> dict:
    """Bytes the store uses, by part, and the free space of its file system.

    One walk of the data folder (:func:`disk_usage_steps` run to its end): the check of
    ``/api/health``'s counters (``fpscan.service.storage.usage.DiskUsage.reconcile``, in a thread
    of its own).

    Parameters
    ----------
    data_dir : str or os.PathLike
        The data folder (``settings.data_dir``).

    Returns
    -------
    dict
        ``{"total_bytes", "scans_bytes", "results_bytes", "datasets_bytes",
        "exports_bytes", "other_bytes", "free_bytes"}`` (int; ``free_bytes`` None when it
        cannot be read).
    """
    steps = disk_usage_steps(data_dir)
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def disk_usage_steps(data_dir: str | os.PathLike) -> Generator[None, None, dict]:
    """:func:`disk_usage` as a generator, so a caller on an event loop may let other work run.

    One pass over the data folder (files counted by ``lstat`` size, symbolic links not
    followed below a part's own folder); a file that vanishes during the walk counts 0.

    Parameters
    ----------
    data_dir : str or os.PathLike
        The data folder (``settings.data_dir``).

    Yields
    ------
    None
        After every :data:`DISK_WALK_STEP` entries.

    Returns
    -------
    dict
        The answer, as :func:`disk_usage` gives it (the generator's ``StopIteration.value``).
    """
    data = Path(data_dir)
    sizes = dict.fromkeys(DISK_PARTS, 0)
    other = 0
    seen = 0
    if data.is_dir():
        # (folder, the part it counts to: "" for other_bytes, None for the data folder itself,
        # whose folders named like a part are that part, followed if they are links)
        todo: list[tuple[str, str | None]] = [(str(data), None)]
        while todo:
            folder, part = todo.pop()
            try:
                with os.scandir(folder) as entries:
                    listed = list(entries)
            except OSError:
                continue
            for entry in listed:
                seen += 1
                if seen % DISK_WALK_STEP == 0:
                    yield
                try:
                    if part is None and entry.name in sizes and entry.is_dir():
                        todo.append((entry.path, entry.name))
                        continue
                    if entry.is_dir():  # a link to a folder elsewhere is not followed (nor counted)
                        if not entry.is_symlink():
                            todo.append((entry.path, part or ""))
                        continue
                    size = entry.stat(follow_symlinks=False).st_size
                except OSError:
                    continue
                if part:
                    sizes[part] += size
                else:
                    other += size
    out: dict[str, int | None] = {f"{k}_bytes": v for k, v in sizes.items()}
    out["other_bytes"] = other  # the database, plans, logs
    out["total_bytes"] = other + sum(sizes.values())
    out["free_bytes"] = free_bytes(data if data.exists() else data.parent)
    return out
