"""A sparse scan out of dense data: ``fpscan.subsample`` (the library),
``fpscan recon FILE --plan PLAN.json`` (the command line, locally and with ``--server``) and a reconstruction of a dataset with
a ``plan_id`` (HTTP) give the replay scan's point data and image to the last bit.

Oracle: the replay scan itself: the simulated scanner (``fpscan.driver.simulator`` with
``fpscan.driver.sources.ReplaySource``, docs/protocol.md Appendix B) on a real pty, scanned by the host
driver into a scan file, read and reconstructed as every scan is."""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

import fpscan
from fpscan.driver.acquire import acquire
from fpscan.driver.simulator import SimConfig, SimulatedScanner
from fpscan.driver.sources import ReplaySource

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def replayed(shared_data, tmp_path_factory):
    """An equi-steradian plan on a 48 × 48 lattice centred on the k-Wave file's 96 × 96 grid, its
    replay scan file, and the file."""
    tmp = tmp_path_factory.mktemp("replay")
    kwave = shared_data / "kwave3d_balls_yarn.h5"
    plan = fpscan.make_plan("equisteradian", lattice=fpscan.Lattice(48, 48, 6e-5),
                            params={"depth": 1.2e-3, "n_points": 150},
                            acquisition={"n_t": 300, "dt": 8e-9, "prf": 0})
    plan.to_json(tmp / "plan.json")
    with SimulatedScanner(SimConfig(source=ReplaySource(kwave), prf=0.0)) as sim:
        assert acquire(sim.path, plan.to_dict(), tmp / "scan.h5").complete
    return {"plan": plan, "plan_path": tmp / "plan.json", "scan": tmp / "scan.h5", "kwave": kwave, "tmp": tmp}


def test_subsample_equals_the_replay_scan_to_the_last_bit(replayed):
    plan = replayed["plan"]
    scan = fpscan.load_dataset(replayed["scan"])
    dense = fpscan.load_dataset(replayed["kwave"])
    sparse = fpscan.subsample(dense, plan)
    assert sparse.alines.shape == scan.alines.shape == (plan.n_points, 300)
    np.testing.assert_array_equal(sparse.alines, scan.alines)  # bit for bit
    np.testing.assert_array_equal(sparse.positions, scan.positions)
    np.testing.assert_array_equal(sparse.weights, scan.weights)
    a, b = fpscan.reconstruct(sparse, "nedner"), fpscan.reconstruct(scan, "nedner")
    np.testing.assert_array_equal(a.p0, b.p0)
    # the same image, placed on the file's own sensor coordinates; the scan knows only its lattice
    np.testing.assert_allclose(a.x - b.x, dense.lateral_shift[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(a.y - b.y, dense.lateral_shift[1], rtol=0, atol=1e-15)
    # unquantised: the file's own values at the mask's points
    raw = fpscan.subsample(dense, plan, quantise=False)
    idx = plan.indices_array() + 24
    np.testing.assert_array_equal(raw.alines, dense.data[:300, idx[:, 1], idx[:, 0]].T.astype(np.float64))


def test_masks_that_do_not_fit_are_refused_with_the_reason(replayed):
    dense = fpscan.load_dataset(replayed["kwave"])
    with pytest.raises(ValueError, match="pitch 0.0001 m differs from the data's dx 6e-05 m"):
        fpscan.subsample(dense, fpscan.make_mask("full", fpscan.Lattice(8, 8, 1e-4)))
    with pytest.raises(ValueError, match="does not sit centred"):
        fpscan.subsample(dense, fpscan.make_mask("full", fpscan.Lattice(47, 48, 6e-5)))
    with pytest.raises(ValueError, match="line lattice cannot sample 2-D sensor data"):
        fpscan.subsample(dense, fpscan.make_mask("full", fpscan.Lattice(8, 1, 6e-5)))
    with pytest.raises(ValueError, match="n_t 800 exceeds the data's 751 samples"):
        fpscan.subsample(dense, fpscan.make_plan("full", lattice=fpscan.Lattice(8, 8, 6e-5),
                                                 acquisition={"n_t": 800, "dt": 8e-9}))
    sparse = fpscan.subsample(dense, fpscan.make_mask("full", fpscan.Lattice(4, 4, 6e-5)))
    with pytest.raises(ValueError, match="needs dense data"):
        fpscan.subsample(dataclasses.replace(sparse, indices=sparse.indices[:3], alines=sparse.alines[:3],
                                             positions=sparse.positions[:3]), replayed["plan"])


def test_the_command_line_with_a_plan_equals_the_replay_scan(replayed):
    tmp = replayed["tmp"]
    cli = [sys.executable, "-m", "fpscan", "recon"]
    for src, out in ((replayed["kwave"], "from-dense"), (replayed["scan"], "from-scan")):
        extra = ["--plan", str(replayed["plan_path"])] if out == "from-dense" else []
        r = subprocess.run([*cli, str(src), *extra, "--method", "nedner", "--out", str(tmp / out), "--quiet"],
                           capture_output=True, text=True, timeout=240)
        assert r.returncode == 0, r.stderr
    a = fpscan.read_result(tmp / "from-dense" / "volume.h5")
    b = fpscan.read_result(tmp / "from-scan" / "volume.h5")
    np.testing.assert_array_equal(a.p0, b.p0)
    r = subprocess.run([*cli, str(replayed["scan"]), "--plan", str(replayed["plan_path"]), "--out",
                        str(tmp / "no")], capture_output=True, text=True, timeout=240)
    assert r.returncode != 0 and "--plan" in r.stderr and "dense" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_over_http_a_dataset_and_a_plan_equal_the_replay_scan(replayed, server):
    """A dataset id plus a plan id: the server subsamples the stored dense dataset."""
    tmp = replayed["tmp"]
    with fpscan.Client(server.url, token=server.token) as api:
        plan_id = api.create_plan(json.loads(replayed["plan_path"].read_text())).id
        assert plan_id == replayed["plan"].id
        ds_id = api.upload_dataset(replayed["kwave"], "kwave-hdf5")
        job = api.start_reconstruction(dataset_id=ds_id, plan_id=plan_id, method="nedner")
        api.wait(job)
        api.download_volume(job, tmp / "http.h5")
        # an option the method does not take, in the request's own field names
        with pytest.raises(fpscan.ApiError, match=r"takes no option lam \(its options: sound_speed, sound_speed_range, force, eps,"):
            api.start_reconstruction(dataset_id=ds_id, plan_id=plan_id, method="nedner", params={"lam": 0.1})
        with pytest.raises(fpscan.NotFound, match="no plan"):
            api.start_reconstruction(dataset_id=ds_id, plan_id="0" * 64, method="nedner")
        with pytest.raises(fpscan.ApiError, match="pitch"):
            other = api.create_plan({"kind": "full", "lattice": {"n_x": 8, "n_y": 8, "pitch": 1e-4},
                                     "acquisition": {"n_t": 100, "dt": 8e-9}}).id
            api.start_reconstruction(dataset_id=ds_id, plan_id=other, method="nedner")
    # the command line's --plan with --server: the plan stored there, the upload sampled by the job
    r = subprocess.run([sys.executable, "-m", "fpscan", "recon", str(replayed["kwave"]), "--plan",
                        str(replayed["plan_path"]), "--server", server.url, "--token", server.token,
                        "--method", "nedner", "--out", str(tmp / "cli-server"), "--quiet"],
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    want = fpscan.reconstruct(fpscan.load_dataset(replayed["scan"]), "nedner")
    np.testing.assert_array_equal(fpscan.read_result(tmp / "http.h5").p0, want.p0)
    np.testing.assert_array_equal(fpscan.read_result(tmp / "cli-server" / "volume.h5").p0, want.p0)
