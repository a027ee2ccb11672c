"""Worker priority is a setting: ``Settings.worker_nice`` (default 0, the
server's own priority) is the CPU priority increment of the reconstruction workers, and
the local pool starts its workers with the server (warming them up in the background)."""
from __future__ import annotations

import os
import time

import pytest

from fpscan.service.jobs.executors import LocalExecutor
from fpscan.service.jobs.work import worker_pid
from fpscan.service.settings import Settings
from tests.service.service_servers import Server
from tests.waits import HANG_S


def priority(pid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, pid)


def test_the_default_worker_priority_is_the_servers():
    assert Settings().worker_nice == 0
    with pytest.raises(ValueError, match="worker_nice"):
        Settings(worker_nice=-1)  # raising a priority needs privileges: refused up front


@pytest.mark.parametrize("nice", [0, 4])
def test_local_workers_run_at_the_configured_increment(nice):
    ex = LocalExecutor(1, nice=nice)
    try:
        pid = ex.run(worker_pid)
        assert pid != os.getpid()
        assert priority(pid) == min(19, priority(0) + nice)
    finally:
        ex.close()


def spawned_at(srv: Server, increment: int) -> list:
    """The server's spawned workers at the server's priority + ``increment``."""
    base = priority(srv.proc.pid)
    return [p for p in srv.workers() if "spawn_main" in " ".join(p.cmdline()) and p.nice() == base + increment]


def wait_spawned_at(srv: Server, increment: int) -> list:
    """:func:`spawned_at` once it finds any (a worker sets its own priority as it starts), or []
    after ``HANG_S``."""
    deadline = time.monotonic() + HANG_S
    while not (found := spawned_at(srv, increment)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return found


@pytest.mark.timeout(120)
def test_a_server_starts_its_workers_at_the_configured_priority(tmp_path):
    """A real server with ``FPSCAN_WORKER_NICE=3``: its reconstruction worker is started
    with the server (before any job) at the server's priority + 3 (none at the old +10)."""
    srv = Server(tmp_path / "data", env={"FPSCAN_WORKER_NICE": "3", "FPSCAN_WARM_UP": "false"}).start()
    try:
        base = priority(srv.proc.pid)
        found = wait_spawned_at(srv, 3)
        assert found, [(p.pid, p.nice()) for p in srv.workers()]
        assert not [p for p in srv.workers() if p.nice() >= base + 10]
        with srv.client() as api:
            assert api.get("/api/health").status_code == 200
    finally:
        srv.stop()


@pytest.mark.timeout(120)
def test_with_the_warm_up_off_the_plan_and_preview_workers_start_at_their_first_use(tmp_path):
    """``FPSCAN_WARM_UP=false``: a healthy server has started neither its plan worker (+8)
    nor its live-preview worker (+5), nothing being warmed (each was 1.2-2.4 s of CPU at every
    start); the first plan request starts the plan worker and is answered."""
    from fpscan.service.api.plans import PLAN_WORKER_NICE
    from fpscan.service.jobs.preview import PREVIEW_WORKER_NICE

    srv = Server(tmp_path / "data", env={"FPSCAN_WARM_UP": "false"}).start()
    try:
        with srv.client() as api:
            assert api.get("/api/health").status_code == 200
            assert spawned_at(srv, PLAN_WORKER_NICE) == [] and spawned_at(srv, PREVIEW_WORKER_NICE) == []
            r = api.post("/api/plans", json={"lattice": {"n_x": 4, "n_y": 4, "pitch": 1e-4},
                                             "points": [[0, 0], [1, 2], [3, 3]]})
            assert r.status_code == 201, r.text
            assert r.json()["n_points"] == 3
            assert len(spawned_at(srv, PLAN_WORKER_NICE)) == 1
            assert spawned_at(srv, PREVIEW_WORKER_NICE) == []
    finally:
        srv.stop()


@pytest.mark.timeout(300)
def test_a_warming_server_is_healthy_and_runs_the_first_job(tmp_path):
    """With the warm-up on (the default), health answers while the worker warms, and a
    job submitted at once queues behind the warm-up and succeeds in that worker."""
    import io

    import numpy as np

    srv = Server(tmp_path / "data", env={"FPSCAN_WARM_UP": "true"}).start()
    try:
        with srv.client(timeout=60) as api:
            assert api.get("/api/health").status_code == 200
            buf = io.BytesIO()
            np.save(buf, np.random.default_rng(0).standard_normal((64, 8, 8)).astype(np.float32))
            r = api.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                         files={"file": ("d.npy", buf.getvalue())})
            assert r.status_code == 201, r.text
            jid = api.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "ner",
                                                         "params": {"dtype": "float32"}}).json()["id"]
            from tests.service.service_servers import wait_job

            done = wait_job(api, jid, timeout=240)
            assert done["state"] == "succeeded", done
            timings = done["params"]["result"]["timings"]
            assert timings["reconstruct_s"] > 0 and timings["write_s"] > 0
        from fpscan.service.api.plans import PLAN_WORKER_NICE
        from fpscan.service.jobs.preview import PREVIEW_WORKER_NICE

        # the plan and live-preview workers were started (and warmed) with the server
        assert len(wait_spawned_at(srv, PLAN_WORKER_NICE)) == 1
        assert len(wait_spawned_at(srv, PREVIEW_WORKER_NICE)) == 1
    finally:
        srv.stop()


GATED_WARM_UP = r"""
import sys, threading
from fpscan.service.jobs import work

with work.JOB_GATE.busy():  # a job is running in this worker
    rest = threading.Thread(target=work._warm_rest, daemon=True)
    rest.start()
    assert work.JOB_GATE.waited.wait(HANG_S), "the background warm-up never reached its gate"
    # it yielded before its first step: nothing of the model is loaded
    before = sorted(m for m in ("fpscan.service.recon.operator", "pylops") if m in sys.modules)
    assert rest.is_alive()
rest.join(HANG_S)
after = sorted(m for m in ("fpscan.service.recon.operator", "pylops") if m in sys.modules)
print(repr((before, after, rest.is_alive())))
"""


def test_the_background_warm_up_waits_while_a_job_runs():
    """The worker's background warm-up (the model-based operator, pylops) takes no
    CPU from a job: each of its steps waits until no job runs, so the first job after start-up
    runs at full speed (in a fresh interpreter: nothing is loaded yet)."""
    import ast
    import subprocess
    import sys

    code = f"HANG_S = {HANG_S}\n" + GATED_WARM_UP
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=HANG_S)
    assert out.returncode == 0, out.stderr[-2000:]
    before, after, alive = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    assert before == []
    assert after == sorted(["pylops", "fpscan.service.recon.operator"])
    assert not alive


def test_the_gate_stays_shut_for_a_quiet_period_after_each_job():
    """``JobGate.wait_quiet``: blocked while a job runs (it says so), and after the job ends
    it returns no sooner than the quiet period — a lower bound, which a loaded machine can
    only lengthen; with no job and ``since`` long past it returns at once."""
    import threading
    import time

    from fpscan.service.jobs.work import JobGate

    gate, quiet, returned = JobGate(), 0.3, []
    with gate.busy():
        waiter = threading.Thread(target=lambda: (gate.wait_quiet(quiet), returned.append(time.monotonic())))
        waiter.start()
        assert gate.waited.wait(HANG_S), "wait_quiet did not block on the running job"
        assert not returned
        ended = time.monotonic()
    waiter.join(HANG_S)
    assert returned and returned[0] - ended >= quiet, (returned, ended)
    idle = JobGate()
    idle.wait_quiet(quiet, since=time.monotonic() - 10 * quiet)  # no job, the period long over
    assert not idle.waited.is_set()


WARM_HEAP = """
import resource
import numpy as np
from fpscan.service.jobs.work import HEAP_WARM_BYTES, warm_heap
assert 3 * (16 << 20) <= HEAP_WARM_BYTES
if not warm_heap():
    print(repr(None))
else:
    arrays, faults = [], []
    for _ in range(3):  # three work arrays of 16 MiB at once: 48 MiB, within the warmed heap
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        a = np.empty(4 << 20, dtype=np.float32)
        a.fill(1.0)  # written: a fresh page faults in here
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
        arrays.append(a)
    print(repr((faults, (4 << 20) * 4 // resource.getpagesize())))
"""


def test_a_warmed_heap_serves_a_first_jobs_arrays_from_pages_already_written():
    """After ``warm_heap`` (the last step of a worker's warm-up) arrays of a first
    job's size (below glibc's mmap threshold, within `HEAP_WARM_BYTES` together) reuse heap
    pages the warm-up wrote: (almost) no page faults, where a fresh process faults in each
    array's pages on its first write. In a fresh interpreter, so that no earlier allocation
    has moved glibc's thresholds; skipped where the C library has no ``mallopt``."""
    import ast
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", WARM_HEAP], capture_output=True, text=True, timeout=HANG_S)
    assert out.returncode == 0, out.stderr[-2000:]
    result = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    if result is None:
        pytest.skip("this C library has no mallopt (not glibc)")
    faults, pages = result
    assert max(faults) < pages // 64, (faults, pages)
