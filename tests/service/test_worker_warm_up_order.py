"""A server's worker is ready for its first job once the kernels of the default
precision are loaded; the other precision and tv come after, in the background, while no job
runs (so a set-up that compiled only float32, as ``scripts/demo.sh`` does, does not make the
first job wait for float64's compilation)."""
from __future__ import annotations

import ast
import subprocess
import sys

from tests.waits import HANG_S

WORKER = r"""
import threading
from fpscan.physics import nufft_kernels
from fpscan.service.jobs import work
from fpscan.service.recon.limits import DEFAULT_DTYPE

def signatures():
    return sorted({str(sig[0].dtype) for sig in nufft_kernels.interp_kernel.overloads})

with work.JOB_GATE.busy():  # a job arrives as the worker starts: the background steps wait
    work.warm_up(full=True, rest_in_background=True)
    ready = signatures()  # what the first job found compiled
    assert work.JOB_GATE.waited.wait(HANG_S), "the background warm-up never reached its gate"
    rest = next(t for t in threading.enumerate() if t.name == "warm-up-rest")
rest.join(HANG_S)
print(repr((DEFAULT_DTYPE, ready, signatures(), rest.is_alive())))
"""


def test_the_first_job_waits_only_for_the_default_precision():
    """In a fresh interpreter: when ``warm_up`` returns (the worker takes jobs), NEDNER/NER's
    interpolation kernel is loaded for the default precision only (complex64 rows: float32);
    the background steps, once no job runs, add the other precision (complex128)."""
    code = f"HANG_S = {HANG_S}\n" + WORKER
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=2 * HANG_S)
    assert out.returncode == 0, out.stderr[-2000:]
    default, ready, later, alive = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    assert default == "float32"
    assert ready == ["complex64"]
    assert later == ["complex128", "complex64"]
    assert not alive
