"""One default method: a grid dataset reconstructed without ``--method`` / ``method`` gets
the same method (``fpscan.service.pipeline.default_method``: ner for grid data) and the same
volume locally (``fpscan recon``), with ``fpscan recon --server`` and through a bare API
request without ``method``.

Oracles: the rule's own answer for the loaded dataset (``default_method`` on
``load_dataset``'s result), the job record the server keeps, and the local volume for the
remote ones (within 1e-6 of the peak: the server's worker runs with other thread counts)."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from fpscan.clients.http import Client
from tests.clients.clients_servers import clean_env, has_command
from tests.clients.test_clients_cli import fpscan
from tests.waits import HANG_S

TOKEN = "default-method-token"
DT, DX = 2e-8, 1e-4

pytestmark = pytest.mark.skipif(not has_command("serve"), reason="`fpscan serve` not available")


def _p0(path):
    with h5py.File(path, "r") as f:
        return f["p0"][()]


def test_grid_without_method_same_method_and_volume_locally_and_over_http(server, tmp_path):
    from fpscan.service.pipeline import default_method
    from fpscan.service.storage.loader import load_dataset

    rng = np.random.default_rng(12)
    data = rng.standard_normal((48, 10, 12)).astype(np.float32)  # (n_t, n_y, n_x): grid data
    src = tmp_path / "grid.npy"
    np.save(src, data)
    expected = default_method(load_dataset(src, "npy", dt=DT, dx=DX))
    assert expected == "ner"

    env = clean_env(FPSCAN_TOKEN=TOKEN)
    common = ["--dt", DT, "--dx", DX, "--quiet"]
    local = fpscan("recon", src, *common, "--out", tmp_path / "local", env=env)
    assert local.returncode == 0, local.stderr
    assert f"method {expected}" in local.stdout
    remote = fpscan("recon", src, *common, "--server", server, "--out", tmp_path / "remote", env=env)
    assert remote.returncode == 0, remote.stderr
    assert f"method {expected}" in remote.stdout

    with Client(server, token=TOKEN) as api:  # the bare API: no "method" in the request body
        ds = api.upload_dataset(src, "npy", dt=DT, dx=DX)
        job_id = api.start_reconstruction(dataset_id=ds)
        job = api.wait(job_id, timeout=HANG_S)
        assert job.params["method"] == expected
        api.download_volume(job_id, tmp_path / "api.h5")

    a = _p0(tmp_path / "local" / "volume.h5")
    tol = 1e-6 * np.abs(a).max()
    for other in (tmp_path / "remote" / "volume.h5", tmp_path / "api.h5"):
        b = _p0(other)
        assert b.shape == a.shape and b.dtype == a.dtype
        np.testing.assert_allclose(b, a, rtol=0, atol=tol)
