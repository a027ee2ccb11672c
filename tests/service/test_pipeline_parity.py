"""One input, one method, one volume: the same scan files (sparse mask and full lattice)
and the same k-Wave file reconstructed locally (``fpscan recon``, in process), through the
job worker (``fpscan.service.jobs.work.run_reconstruction``) and over HTTP (upload + job on a
real uvicorn server) give identical volumes, for every method of ``fpscan.service.pipeline``.

Oracles: the three paths against each other — bit-identical locally vs the worker (same
process), within 1e-6 of the peak over HTTP (the server's worker process runs with other
thread counts) — and each volume's method and shape against the request. A method that
needs a full grid is refused on a sparse mask by all three paths alike.
"""
from __future__ import annotations

import argparse
import io
import json
import math

import h5py
import numpy as np
import pytest

from fpscan.clients.cli import build_parser
from fpscan.clients.cli import main as fpscan_main
from fpscan.driver.plan import plan_id_of
from fpscan.driver.scanfile import META_KEYS, ScanFile
from fpscan.service.jobs.work import run_reconstruction
from fpscan.service.pipeline import METHODS
from tests.service.service_servers import Server, needs_recon, wait_job

pytestmark = needs_recon

PITCH, N_X, N_Y, N_T, DT, C = 1e-4, 6, 5, 40, 2e-8, 1490.0
INPUTS = ("scan-full", "scan-sparse", "kwave")
CASES = [(i, m) for i in INPUTS for m in METHODS]
#: options other than the defaults, the same on all three paths (so that they are shown to
#: travel through each); an iterative method gets few iterations to keep the test short
OPTIONS = {"ner": {"upsample": 2}, "linear": {"positivity": True}, "cubic": {"dtype": "float64"},
           "kwave": {"interp": "*linear"}, "tv": {"max_iter": 4}}


def _cli_flags(options: dict) -> list[str]:
    """``fpscan recon``'s flags for ``options`` (found by the parser's option names)."""
    recon = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices["recon"]
    by_dest = {a.dest: a for a in recon._actions}
    flags = []
    for name, value in options.items():
        action = by_dest[name]
        flag = next(o for o in action.option_strings if o.startswith("--"))
        if action.nargs == 0:  # a switch (--positivity, or --no-positivity for False)
            flags.append(flag if value else f"--no-{flag[2:]}")
        else:
            flags += [flag, str(value)]
    return flags


def _plan(indices) -> dict:
    pos = [[(i - (N_X - 1) / 2) * PITCH, (j - (N_Y - 1) / 2) * PITCH] for i, j in indices]
    plan = {"format": "fpscan-plan/1", "lattice": {"n_x": N_X, "n_y": N_Y, "pitch": PITCH},
            "mask": {"kind": "points", "params": {}},
            "points": {"indices": [list(p) for p in indices], "positions": pos,
                       "weights": [PITCH ** 2] * len(indices)},
            "order": "rows",
            "acquisition": {"n_t": N_T, "dt": DT, "averages": 1, "wavelengths": [7.5e-7], "prf": 0.0,
                            "sound_speed": C}}
    plan["id"] = plan_id_of(plan)
    return plan


def _scan(path, indices) -> None:
    from fpscan.physics import Ball, ball_alines

    plan = _plan(indices)
    pos = np.asarray(plan["points"]["positions"], float)
    alines = ball_alines(pos, [Ball(x=1e-4, y=0.0, z=0.35e-3, radius=1e-4, amplitude=1.0)], DT, N_T, C)
    scale = np.abs(alines).max() / 20000
    with ScanFile.create(path, plan, instrument={"idn": "test"}, software_version="test") as sf:
        for k in range(len(pos)):
            meta = dict.fromkeys(META_KEYS, 0)
            meta.update(point_index=k, dc_level=1.0 + 0.01 * k, scale=scale, offset=0.0, dt_s=DT)
            sf.append(k, np.round(alines[k] / scale).astype(np.int16), meta)


def _kwave(path, shared) -> None:
    """A small piece of k-Wave's own 3-D simulation, in k-Wave's layout and attributes."""
    src = shared / "kwave3d_balls_yarn.h5"
    with h5py.File(src, "r") as f, h5py.File(path, "w") as g:
        d = f["sensor_data/clean"]
        g.create_dataset("sensor_data/clean", data=d[:N_T, 40:47, 38:46])
        g["sensor_data/clean"].attrs.update(dict(d.attrs))
        g.attrs.update(dict(f.attrs))


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, shared_data):
    folder = tmp_path_factory.mktemp("parity")
    full = [(i, j) for j in range(N_Y) for i in range(N_X)]
    sparse = full[::3]
    paths = {"scan-full": folder / "full.h5", "scan-sparse": folder / "sparse.h5", "kwave": folder / "kw.h5"}
    _scan(paths["scan-full"], full)
    _scan(paths["scan-sparse"], sparse)
    _kwave(paths["kwave"], shared_data)
    return paths


@pytest.fixture(scope="module")
def remote(inputs, tmp_path_factory):
    """One server; every input uploaded and every (input, method) job started up front."""
    srv = Server(tmp_path_factory.mktemp("parity-srv") / "data").start()
    try:
        jobs = {}
        with srv.client() as c:
            for name, path in inputs.items():
                fmt = "kwave-hdf5" if name == "kwave" else "fpscan"
                r = c.post("/api/datasets", data={"format": fmt},
                           files={"file": (path.name, path.read_bytes(), "application/octet-stream")})
                assert r.status_code == 201, r.text
                ds = r.json()["dataset_id"]
                for m in METHODS:
                    r = c.post("/api/reconstructions",
                               json={"dataset_id": ds, "method": m, "params": OPTIONS.get(m, {})})
                    jobs[name, m] = r
        yield srv, jobs
    finally:
        srv.stop()


def _volume(path):
    with h5py.File(path, "r") as f:
        return f["p0"][()], dict(f.attrs)


@pytest.mark.parametrize(("name", "method"), CASES)
def test_local_worker_and_http_give_one_volume(name, method, inputs, remote, tmp_path, capsys):
    path = inputs[name]
    srv, jobs = remote
    refused = name == "scan-sparse" and METHODS[method].needs_grid
    # local: the CLI in this process
    options = OPTIONS.get(method, {})
    rc = fpscan_main(["recon", str(path), "--method", method, *_cli_flags(options), "--out", str(tmp_path / "local"),
                      "--quiet"])
    err = capsys.readouterr().err
    # the job worker, on the scan file itself (a scan job's input)
    spec_input = {"kind": "scan", "path": str(path)} if name.startswith("scan") else None
    if spec_input is None:  # the canonical dataset file an upload becomes
        from fpscan.service.storage.loader import import_dataset

        folder = tmp_path / "ds"
        folder.mkdir()
        meta = import_dataset(path, folder, "kwave-hdf5", dt=None, dx=None, dy=None, sound_speed=None, key=None)
        spec_input = {"kind": "dataset", "path": str(folder / meta["path"])}
    spec = {"input": spec_input, "params": {"method": method, **options}, "out_dir": str(tmp_path / "worker")}
    http = jobs[name, method]
    if refused:
        assert rc != 0 and "lattice point" in err, err
        with pytest.raises(ValueError, match="lattice point"):
            run_reconstruction(spec)
        assert http.status_code == 422 and "full regular grid" in http.json()["detail"]
        return
    assert rc == 0, err
    run_reconstruction(spec)
    assert http.status_code == 202, http.text
    with srv.client() as c:
        job = wait_job(c, http.json()["id"])
        assert job["state"] == "succeeded", job
        r = c.get(f"/api/reconstructions/{job['id']}/volume.h5")
        assert r.status_code == 200
        remote_p0, remote_attrs = _volume(io.BytesIO(r.content))
    local_p0, local_attrs = _volume(tmp_path / "local" / "volume.h5")
    worker_p0, worker_attrs = _volume(tmp_path / "worker" / "volume.h5")
    assert local_attrs["method"] == worker_attrs["method"] == remote_attrs["method"] == method
    # one default precision (float32) everywhere, unless asked for
    assert local_p0.dtype == worker_p0.dtype == remote_p0.dtype == np.dtype(options.get("dtype", "float32"))
    for attrs in (local_attrs, worker_attrs, remote_attrs):  # the options were used on every path
        used = json.loads(attrs["params"])
        for name, value in options.items():
            assert used.get(name) == value, (name, used)
    # the default depth grid (fpscan.service.recon.depth): the pitch down to c·t_last; kwave: k-Wave's own, n_t
    # rows of c·dt; tv: at the pitch's band down to the last echo (fpscan.service.recon.tv.grid), no deeper
    pitch, dt, c = (60e-6, 8e-9, 1500.0) if path == inputs["kwave"] else (PITCH, DT, C)
    rows = math.floor(c * (N_T - 1) * dt / pitch) + 1  # 12 rows of 0.1 mm (scans), 8 of 60 µm (k-Wave)
    if method == "kwave":
        rows = N_T
    elif method == "tv":
        used = json.loads(local_attrs["params"])
        assert used["n_z"] <= rows and used["dz"] == pytest.approx(pitch)
        rows = used["n_z"]
    assert local_p0.shape[0] == rows and local_p0.ndim == 3
    assert np.abs(local_p0).max() > 0
    np.testing.assert_array_equal(worker_p0, local_p0)
    np.testing.assert_allclose(remote_p0, local_p0, rtol=0, atol=1e-6 * np.abs(local_p0).max())
