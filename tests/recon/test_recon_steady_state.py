"""A reconstruction repeated, and the model-based operator pair applied again and again, fault in
no fresh pages: their work arrays come back from the work-array pool (`fpscan.physics.workspace`)
with their pages mapped, and every copy between the transforms writes each entry of its output,
so nothing needs zeroing first. An image a caller keeps is never lent again, and calls from
several threads at once get buffers of their own."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from fpscan.physics import fft_engine, workspace
from fpscan.service.recon import PlanarOperator, reconstruct_grid, reconstruct_points

# minor page faults of the third call in a fresh interpreter, transparent huge pages off for the
# process (prctl PR_SET_THP_DISABLE: every fault a 4 KiB page, so that the count is the pages
# first written), against the pages of the call's largest work arrays
FAULTS_SCRIPT = r"""
import ctypes, json, resource, sys
ctypes.CDLL(None).prctl(41, 1, 0, 0, 0)  # PR_SET_THP_DISABLE
import numpy as np
from fpscan.physics import nufft
from fpscan.service.recon import PlanarOperator, reconstruct_grid

case = sys.argv[1]
rng = np.random.default_rng(0)
if case == "ner":
    n_t, n = 512, 128
    data = rng.standard_normal((n_t, n, n)).astype(np.float32)
    call = lambda: reconstruct_grid(data, 1e-4, 1e-4 / 1500, 1500.0, dtype=np.float32, device="cpu")
    cols = n * (n // 2 + 1)
    work = (cols * nufft.make_grid(n_t, "nufft", 1e-6).L + (n_t + 1) * cols) * 8  # the fine grid, the spectrum
elif case == "load":  # a job worker's input: the canonical dataset file read again
    import os, tempfile
    from fpscan.service.recon.dataset import GridDataset
    from fpscan.service.storage.loader import load_dataset, write_dataset
    path = os.path.join(tempfile.mkdtemp(), "ds.h5")
    data = rng.standard_normal((512, 128, 128)).astype(np.float32)
    write_dataset(path, GridDataset(data=data, dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0, dy=1e-4))
    call = lambda: load_dataset(path, "dataset")
    work = data.nbytes
else:
    kw = dict(positions=None, band=None)
    if case == "pair at nodes":  # a scan plan's points on the lattice, tv's band limit
        x = (np.arange(64) - 31.5) * 1e-4
        X, Y = np.meshgrid(x, x)
        keep = rng.random(X.size) < 0.3
        kw = dict(positions=np.column_stack([X.ravel()[keep], Y.ravel()[keep]]), band=3e6)
    op = PlanarOperator((48, 64, 64), 1e-4, 1e-4, 1e-4 / 1500, 160, 1500.0, dtype=np.float32, device="cpu", **kw)
    v = rng.standard_normal(op.ishape).astype(np.float32)
    call = lambda: op.adjoint(op.forward(v))
    n_z2, n_y2, n_x2 = op.padded_shape
    work = max(n_z2, 160) * n_y2 * (n_x2 // 2 + 1) * 8  # the k-space
for _ in range(2):
    call()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
call()
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(json.dumps({"faults": faults, "work_pages": work // 4096}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux's prctl and page-fault counts")
@pytest.mark.parametrize("case", ["ner", "pair", "pair at nodes", "load"])
def test_a_repeated_call_faults_in_no_fresh_pages(case):
    """NER float32 at 512 x 128² (its fine grid and spectrum: 25 000 pages), a forward +
    adjoint pair of the free-space operator (grid sensors; sensors on lattice nodes with a band
    limit), and a job's input read from its canonical dataset file (512 x 128², 8 000 pages):
    the third call faults in under 5 % of its work arrays' pages. Each work array freshly
    allocated, as before the pool, faults them all in on every call."""
    r = subprocess.run([sys.executable, "-c", FAULTS_SCRIPT, case], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads(r.stdout.strip().splitlines()[-1])
    assert m["faults"] < 0.05 * m["work_pages"], m


def test_an_image_the_caller_keeps_is_never_lent_again():
    """Results of earlier calls, kept, stay as they were while later calls run (their memory is
    busy in the pool), for NER, NEDNER on lattice nodes and the operator's adjoint, whose
    image lies over its k-space."""
    rng = np.random.default_rng(3)
    datas = [rng.standard_normal((256, 40, 48)).astype(np.float32) for _ in range(3)]
    kept = [reconstruct_grid(d, 1e-4, 1e-4 / 1500, 1500.0, dtype=np.float32, device="cpu").p0 for d in datas]
    copies = [k.copy() for k in kept]
    for d, k, c in zip(datas, kept, copies):
        np.testing.assert_array_equal(k, c)
        np.testing.assert_array_equal(k, reconstruct_grid(d, 1e-4, 1e-4 / 1500, 1500.0, dtype=np.float32,
                                                          device="cpu").p0)
    x = (np.arange(40) - 19.5) * 1e-4
    X, Y = np.meshgrid(x, x)
    pos = np.column_stack([X.ravel(), Y.ravel()])[::3]
    al = [rng.standard_normal((len(pos), 256)).astype(np.float32) for _ in range(2)]
    points = [reconstruct_points(a, pos, 1e-4 / 1500, 1500.0, grid=(x, x), dtype=np.float32, device="cpu").p0
              for a in al]
    again = reconstruct_points(al[0], pos, 1e-4 / 1500, 1500.0, grid=(x, x), dtype=np.float32, device="cpu").p0
    np.testing.assert_array_equal(points[0], again)
    assert not np.shares_memory(points[0], points[1])
    op = PlanarOperator((24, 32, 32), 1e-4, 1e-4, 1e-4 / 1500, 64, 1500.0, dtype=np.float32, device="cpu")
    ys = [rng.standard_normal(op.oshape).astype(np.float32) for _ in range(3)]
    images = [op.adjoint(y) for y in ys]
    for y, im in zip(ys, images):
        np.testing.assert_array_equal(im, op.adjoint(y))


def test_threads_at_once_get_buffers_of_their_own():
    """Four threads reconstructing four records at once (each through the pool) give each record's
    image, the one a lone call gives."""
    rng = np.random.default_rng(4)
    datas = [rng.standard_normal((256, 48, 48)).astype(np.float32) for _ in range(4)]
    want = [reconstruct_grid(d, 1e-4, 1e-4 / 1500, 1500.0, dtype=np.float32, device="cpu").p0.copy() for d in datas]
    got: list = [None] * 4
    start = threading.Barrier(4)

    def run(i: int) -> None:
        start.wait()
        for _ in range(3):
            got[i] = reconstruct_grid(datas[i], 1e-4, 1e-4 / 1500, 1500.0, dtype=np.float32, device="cpu").p0

    threads = [threading.Thread(target=run, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for w, g in zip(want, got):
        np.testing.assert_array_equal(g, w)


def test_the_pool_lends_a_free_buffer_and_drops_stale_ones_on_a_miss():
    """`workspace.take`: a buffer whose arrays are all gone is lent again (warm); one a view of a
    view still holds is not; a request no free buffer fits drops the free buffers lent in none
    of the last `workspace.AGE` takes; `release` returns the free buffers' bytes."""
    workspace.release()
    a = workspace.take((1 << 20,), np.float64)  # 8 MiB
    address = a.ctypes.data
    view = a[16:].reshape(-1, 8)[::2]
    del a
    assert workspace.take((1 << 20,), np.float64).ctypes.data != address  # the view holds it
    del view
    b = workspace.take((900_000,), np.float64)
    assert b.ctypes.data == address  # free now, within LARGEST of the request: lent
    del b
    assert workspace.held() == 2 * (8 << 20)  # both free
    kept = [workspace.take((600_000,), np.float64) for _ in range(workspace.AGE + 1)]  # misses, each kept
    assert workspace.held() == sum(k.nbytes for k in kept)  # the stale 8 MiB buffers dropped
    del kept
    assert workspace.release() == (workspace.AGE + 1) * 600_000 * 8
    assert workspace.held() == 0


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs CPU affinity")
def test_the_transforms_run_on_the_cores_the_process_may_use():
    """`fft_engine.workers` counts the cores of the process's CPU set (``taskset``), not the
    machine's: pocketfft's ``workers=-1`` would start a thread per core of the machine on the
    one core the process has."""
    code = ("import os; os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]}); "
            "from fpscan.physics import fft_engine; print(fft_engine.workers())")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert int(r.stdout) == 1
    assert fft_engine.workers() == len(os.sched_getaffinity(0))


def test_an_idle_worker_gives_its_work_arrays_back():
    """A job worker's thread (`fpscan.service.jobs.work.release_when_quiet`) releases the pool's
    free buffers once no job has run for its quiet time after one ended, and keeps them while
    jobs come."""
    import time

    from fpscan.service.jobs.work import JobGate, release_when_quiet
    from tests.waits import HANG_S

    workspace.release()
    gate = JobGate()
    threading.Thread(target=release_when_quiet, args=(gate, 0.0), daemon=True).start()
    with gate.busy():  # a job: its array, dropped at its end, stays in the pool (free)
        workspace.take((1 << 20,), np.float64)
    deadline = time.monotonic() + HANG_S
    while workspace.held() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert workspace.held() == 0
