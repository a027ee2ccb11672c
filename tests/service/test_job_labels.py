"""A reconstruction's record says what its input samples (``params["mask"]``: the plan's mask
kind and points, or the dataset's), and ``fpscan jobs list`` names it from there: a dense
dataset and the same dataset sampled by a sparse plan are told apart."""
from __future__ import annotations

import io
import subprocess
import sys

import numpy as np

import fpscan
from tests.service.service_servers import needs_recon, wait_job
from tests.waits import HANG_S

pytestmark = needs_recon

N, N_T, DT, PITCH = 16, 64, 8e-9, 1e-4


def test_dense_and_plan_sampled_reconstructions_are_labelled_apart(server, api):
    buf = io.BytesIO()
    np.save(buf, np.random.default_rng(5).standard_normal((N_T, N, N)))
    r = api.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(PITCH)},
                 files={"file": ("d.npy", buf.getvalue(), "application/octet-stream")})
    assert r.status_code == 201, r.text
    ds = r.json()["dataset_id"]
    plan = fpscan.make_plan("random", lattice=fpscan.Lattice(N, N, PITCH), params={"n_points": 40, "seed": 1},
                            acquisition={"n_t": N_T, "dt": DT}).to_dict()
    r = api.post("/api/plans", json=plan)
    assert r.status_code in (200, 201), r.text
    plan_id = r.json()["id"]
    n_points = len(plan["points"]["indices"])
    assert n_points < N * N

    r = api.post("/api/reconstructions", json={"dataset_id": ds, "method": "ner"})
    assert r.status_code == 202, r.text
    dense = wait_job(api, r.json()["id"])
    r = api.post("/api/reconstructions", json={"dataset_id": ds, "plan_id": plan_id, "method": "nedner"})
    assert r.status_code == 202, r.text
    sparse = wait_job(api, r.json()["id"])

    # the record: its earlier keys kept, the mask added
    assert dense["params"]["input_id"] == f"dataset:{ds}"
    assert dense["params"]["mask"] == {"kind": "full", "n_points": N * N, "lattice": [N, N]}
    assert sparse["params"]["input_id"] == f"dataset:{ds}+plan:{plan_id}"
    assert sparse["params"]["mask"] == {"kind": "random", "n_points": n_points, "lattice": [N, N],
                                        "plan_id": plan_id}

    out = subprocess.run([sys.executable, "-m", "fpscan", "jobs", "list", "--server", server.url,
                          "--token", server.token], capture_output=True, text=True, timeout=HANG_S)
    assert out.returncode == 0, out.stderr
    assert f"ner of dataset {ds[:8]} (full {N}×{N})" in out.stdout, out.stdout
    assert (f"nedner of dataset {ds[:8]} sampled by plan {plan_id[:8]} (random, {n_points} of {N * N} points)"
            in out.stdout), out.stdout
