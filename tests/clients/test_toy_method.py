"""The toy iterative method of issue 48.1, added as one file (``service/recon/methods/landweber.py``)
and this test: with no other edit it reconstructs from the library (``fpscan.reconstruct``),
``fpscan recon`` (its flags generated from its options), ``fpscan recon --server`` and the HTTP
API (listed by ``GET /api/reconstructions/methods`` as iterative and cancellable, a job that
reports its iterations and is cancelled mid-run); the web page's method choices and option
fields are the server's list (tests/web/test_web_page.py checks every listed method there).

Oracles: the true p0 of the exact forward model (``driver.physics.forward``): Landweber on the
same data correlates better with it than NER does; the local volume for the remote ones."""
from __future__ import annotations

import time

import h5py
import numpy as np
import pytest

from clients.http import Client
from clients.http.errors import JobCancelled
from tests.clients.clients_servers import clean_env, has_command
from tests.clients.test_clients_cli import fpscan
from tests.waits import HANG_S

TOKEN = "toy-method-token"
DX, C, N_T = 1e-4, 1500.0, 48
DT = DX / C

pytestmark = pytest.mark.skipif(not has_command("serve"), reason="`fpscan serve` not available")


def _cc(a, b):
    a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
    return float(a @ b / np.linalg.norm(a) / np.linalg.norm(b))


def _data(tmp_path):
    from driver.physics.forward import forward_grid

    p0 = np.zeros((N_T, 16, 16))
    p0[15:19, 6:10, 5:9] = 1.0
    g = forward_grid(p0, DX, C * DT, DT, N_T).astype(np.float32)  # (n_t, n_y, n_x)
    np.save(tmp_path / "data.npy", g)
    return p0, g


def test_a_method_added_as_one_file_works_everywhere(server, tmp_path):
    import fpscan as lib

    p0, g = _data(tmp_path)
    ds = lib.GridDataset(data=g, dx=DX, dy=DX, dt=DT, c=C)
    rec = lib.reconstruct(ds, "landweber", iterations=30)
    assert rec.params["iterations"] == 30 and rec.params["stop_reason"] in ("iterations", "converged")
    assert _cc(rec.p0, p0) > _cc(lib.reconstruct(ds, "ner").p0, p0) + 0.1, "Landweber no better than NER"

    env = clean_env(FPSCAN_TOKEN=TOKEN)
    common = ["--dt", DT, "--dx", DX, "--method", "landweber", "--iterations", 4, "--quiet"]
    local = fpscan("recon", tmp_path / "data.npy", *common, "--out", tmp_path / "local", env=env)
    assert local.returncode == 0, local.stderr
    remote = fpscan("recon", tmp_path / "data.npy", *common, "--server", server, "--out", tmp_path / "remote",
                    env=env)
    assert remote.returncode == 0, remote.stderr
    with h5py.File(tmp_path / "local" / "volume.h5", "r") as f, h5py.File(tmp_path / "remote" / "volume.h5") as h:
        a, b = f["p0"][()], h["p0"][()]
    assert a.shape == (N_T, 16, 16) and np.abs(a - b).max() <= 1e-4 * np.abs(a).max()

    with Client(server, token=TOKEN) as api:
        info = {m["name"]: m for m in api.methods()}
        assert info["landweber"]["iterative"] and info["landweber"]["cancellable"]
        assert {"iterations", "tol", "positivity"} <= {o["name"] for o in info["landweber"]["options"]}
        dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=DT, dx=DX)
        job = api.wait(api.start_reconstruction(dataset_id=dataset_id, method="landweber", params={"iterations": 3}),
                       timeout=HANG_S)
        assert job.state == "succeeded" and job.params["method"] == "landweber", job
        # a long run is cancelled between its iterations
        long = api.start_reconstruction(dataset_id=dataset_id, method="landweber",
                                          params={"iterations": 100000, "tol": 0})
        deadline = time.monotonic() + HANG_S  # the event: its first iteration reported
        while "iteration" not in (api.get_job(long).progress.stage or ""):
            assert time.monotonic() < deadline, "the toy's first iteration never came"
            time.sleep(0.1)
        api.cancel_job(long)
        with pytest.raises(JobCancelled):
            api.wait(long, timeout=HANG_S)
