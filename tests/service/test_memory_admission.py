"""The memory admission rule (issue 14): computed from the options actually used, it
covers the measured peak of a real reconstruction; the worker applies it again against
the configured limit (not the memory free now) and stops with the reason."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from service.jobs.queue import AdmissionError, estimate_memory, working_depth_rows
from tests.service.service_servers import needs_recon

PEAK_SCRIPT = r"""
import json, resource, sys
import numpy as np
from service.pipeline import reconstruct
from service.storage.datasets import GridDataset
n, n_t, up, dz = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
params = {"upsample": up, "dtype": "float32"}
if dz > 0:
    params["dz"] = dz
data = np.random.default_rng(0).standard_normal((n_t, n, n)).astype(np.float32)
inp = GridDataset(data=data, dx=1e-4, dt=2e-8, c=1500.0, dy=1e-4)
reconstruct(inp, "ner", **{**params, "n_z": 8})  # warm-up: imports, compiled kernels, FFT plans
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
img = reconstruct(inp, "ner", **params)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"base": base, "peak": peak}))
"""


@needs_recon
@pytest.mark.timeout(300)
@pytest.mark.parametrize("n, n_t, up, dz", [(96, 512, 1, 0.0), (64, 256, 2, 1e-5)])
def test_admission_estimate_covers_the_measured_peak(n, n_t, up, dz):
    """Peak resident memory of a real NER reconstruction in a fresh process (above its
    warmed-up baseline, which holds the input) stays below the admission estimate."""
    r = subprocess.run([sys.executable, "-c", PEAK_SCRIPT, str(n), str(n_t), str(up), str(dz)],
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads(r.stdout.strip().splitlines()[-1])
    params = {"method": "ner", "upsample": up, "dtype": "float32", **({"dz": dz} if dz else {})}
    estimate = estimate_memory({"n_t": n_t, "n_x": n, "n_y": n, "dt": 2e-8, "c": 1500.0}, params)
    used = m["peak"] - m["base"]
    assert used < estimate, (used, estimate)


def test_depth_rows_follow_dz_and_absurd_dz_is_refused():
    shape = {"n_t": 256, "n_x": 32, "n_y": 32, "dt": 2e-8, "c": 1500.0}
    assert working_depth_rows(shape, {}) == 256
    # dz = c·dt / 4: four times the rows, and more memory than the default
    assert working_depth_rows(shape, {"dz": 1500.0 * 2e-8 / 4}) >= 4 * 255
    assert estimate_memory(shape, {"dz": 1500.0 * 2e-8 / 4}) > estimate_memory(shape, {})
    with pytest.raises(AdmissionError, match="dz"):
        working_depth_rows(shape, {"dz": 5e-324})


@needs_recon
def test_the_worker_refuses_a_job_over_the_configured_limit(tmp_path):
    import h5py

    from service.jobs.work import run_reconstruction

    path = tmp_path / "dataset.h5"
    with h5py.File(path, "w") as f:
        f.attrs.update({"layout": "grid", "dt": 2e-8, "dx": 1e-4, "c": 1500.0})
        f["data"] = np.random.default_rng(0).standard_normal((128, 24, 24)).astype(np.float32)
    spec = {"input": {"kind": "dataset", "path": str(path)}, "params": {"method": "ner", "upsample": 4},
            "out_dir": str(tmp_path / "out"), "memory_limit": 4 * 2**20}
    with pytest.raises(ValueError, match="memory limit"):
        run_reconstruction(spec)
    assert not (tmp_path / "out").exists()
    spec["memory_limit"] = 8 * 2**30  # the same job under a limit it fits
    assert run_reconstruction(spec)["shape"] == [128, 96, 96]
