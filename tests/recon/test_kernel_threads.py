"""The compiled kernels' OpenMP threads sleep as soon as a kernel ends (`fpscan.physics.threads`):
measured as the CPU time the process's other threads use while the main thread sleeps
right after a parallel kernel (libgomp's default spin: about 8 ms of it a kernel)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_AFTER_KERNEL = r"""
import json, os, threading, time
import numpy as np
from fpscan.physics.nufft import transpose   # imports fpscan.physics first
F = np.ones((512, 1024))
out = np.empty((1024, 512))

def others_cpu_ns():  # on-CPU time of every thread but this one (schedstat: ns)
    me, total = str(threading.get_native_id()), 0
    for tid in os.listdir("/proc/self/task"):
        if tid != me:
            with open(f"/proc/self/task/{tid}/schedstat") as f:
                total += int(f.read().split()[0])
    return total

transpose(F, out)  # compiles or loads the parallel kernel, starts the OpenMP threads
spins = []
for _ in range(5):
    transpose(F, out)
    before = others_cpu_ns()
    time.sleep(0.1)
    spins.append((others_cpu_ns() - before) / 1e6)
import numba
print(json.dumps({"policy": os.environ.get("OMP_WAIT_POLICY"), "spin_ms": spins, "layer": numba.threading_layer()}))
"""


def _run(env_policy: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if env_policy is not None:
        env["OMP_WAIT_POLICY"] = env_policy
    r = subprocess.run([sys.executable, "-c", _AFTER_KERNEL], capture_output=True, text=True, env=env, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="needs Linux's /proc thread statistics")
def test_openmp_threads_sleep_when_a_kernel_ends():
    got = _run(None)
    assert got["policy"] == "PASSIVE"
    if got["layer"] != "omp":
        pytest.skip(f"numba's threading layer here is {got['layer']}, not OpenMP")
    # libgomp's default spins about 8 ms of CPU after each kernel; passive: none
    assert sorted(got["spin_ms"])[2] < 1.0, got


def test_a_wait_policy_the_user_set_is_kept():
    assert _run("ACTIVE")["policy"] == "ACTIVE"
