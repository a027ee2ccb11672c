"""Plugins and the record of the method that ran.

A tiny third-party distribution, written here into a temporary ``sys.path`` folder as an
installer would (its package and its ``.dist-info`` with ``METADATA`` and ``entry_points.txt``;
no network, nothing inside fpscan touched), declares a method ``toy`` (NEDNER's algorithm
registered under another name) and an export format ``toy-text``. A second one declares a
method whose module does not exist. With that folder on ``PYTHONPATH``:

- the library (``fpscan.service.recon.methods.METHODS``, ``fpscan.export_formats``) and the CLI's help
  offer both, and the broken plugin is reported once, by name, on stderr;
- a real ``fpscan serve`` (uvicorn on 127.0.0.1) starts and lists both in ``GET
  /api/reconstructions/methods`` and ``GET /api/formats``; a job run with ``toy`` records
  ``toy`` in the job, in its ``params_used``, in ``volume.h5`` and in its exports (the plugin's
  ``toy-text`` and the built-in ``npz``).

Oracles: the entry points written here, and the files read back with h5py / numpy.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.service.service_servers import TOKEN, Server, needs_recon
from tests.waits import HANG_S

pytestmark = pytest.mark.timeout(300)

N, DX, DT, N_T = 8, 1e-4, 4e-8, 32

METHOD_PY = '''
"""A third-party method: NEDNER's algorithm under the name ``toy``."""
from dataclasses import replace

from fpscan.service.recon.methods.nedner import METHOD as NEDNER

METHOD = replace(NEDNER, name="toy", title="toy (NEDNER under another name)", order=900, default_for=())
'''

FORMAT_PY = '''
"""A third-party export format: a result's method and p0 shape as text."""
from pathlib import Path

from fpscan.service.formats import Format


def export(src, out):
    import h5py

    with h5py.File(src, "r") as f:
        method = f.attrs["method"]
        shape = "x".join(str(n) for n in f["p0"].shape)
    Path(out).write_text(f"method={method}\\nshape={shape}\\n")
    return Path(out)


FORMAT = Format(name="toy-text", title="toy text summary", container="file", export_from="result",
                export=export, suffix=".txt", media_type="text/plain")
'''


def _dist(site, name: str, entry_points: str, files: dict[str, str]) -> None:
    """Install the distribution ``name`` into ``site`` as a wheel would: its files and its
    ``<name>-0.1.dist-info`` (``METADATA``, ``entry_points.txt``)."""
    for rel, text in files.items():
        path = site / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    info = site / f"{name}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    site = tmp_path_factory.mktemp("site")
    _dist(site, "fpscan_toy", """
        [fpscan.methods]
        toy = fpscan_toy.method:METHOD

        [fpscan.formats]
        toy-text = fpscan_toy.text:FORMAT
        """, {"fpscan_toy/__init__.py": "", "fpscan_toy/method.py": METHOD_PY, "fpscan_toy/text.py": FORMAT_PY})
    _dist(site, "fpscan_broken", """
        [fpscan.methods]
        broken = fpscan_broken_nowhere:METHOD
        """, {})
    return site


def _env(site) -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])])}


LIBRARY = r'''
import json
import fpscan
from fpscan.service import plugins
from fpscan.service.recon.methods import METHODS, Method, register
plugins.load_group("fpscan.methods", Method, register)  # loading again reports nothing again
print(json.dumps({"methods": list(METHODS), "exports": list(fpscan.export_formats()),
                  "failures": plugins.failures()}))
'''


def test_a_plugin_reaches_the_library_and_the_cli_and_a_broken_one_is_reported_once(site):
    out = subprocess.run([sys.executable, "-c", LIBRARY], capture_output=True, text=True, timeout=120, env=_env(site))
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["methods"][-1] == "toy" and "nedner" in got["methods"] and "broken" not in got["methods"]
    assert got["exports"][-1] == "toy-text"
    assert list(got["failures"]) == ["fpscan.methods:broken (fpscan_broken)"]
    assert "ModuleNotFoundError" in got["failures"]["fpscan.methods:broken (fpscan_broken)"]
    assert out.stderr.count("'broken'") == 1, out.stderr

    for command, word in (("recon", "toy"), ("export", "toy-text")):
        helped = subprocess.run([sys.executable, "-m", "fpscan", command, "--help"], capture_output=True, text=True,
                                timeout=120, env=_env(site))
        assert helped.returncode == 0, helped.stderr
        assert word in helped.stdout, helped.stdout
        # the methods' entry points load for recon's flags (export's need the formats only)
        assert helped.stderr.count("'broken'") == (command == "recon"), helped.stderr


@needs_recon
def test_a_plugin_method_and_format_are_served_and_the_record_names_the_method(site, tmp_path):
    import h5py

    import fpscan

    srv = Server(tmp_path / "data", env={"PYTHONPATH": _env(site)["PYTHONPATH"]})
    (tmp_path / "data").mkdir()
    srv.start()
    try:
        with srv.client() as http:
            methods = {m["name"]: m for m in http.get("/api/reconstructions/methods").json()}
            assert "toy" in methods and "broken" not in methods
            assert methods["toy"]["title"] == "toy (NEDNER under another name)"
            formats = {f["name"]: f for f in http.get("/api/formats").json()}
            assert formats["toy-text"]["export_from"] == "result" and formats["toy-text"]["suffix"] == ".txt"
        data = np.random.default_rng(4).standard_normal((N_T, N, N)).astype(np.float32)
        np.save(tmp_path / "data.npy", data)
        with fpscan.Client(srv.url, token=TOKEN) as api:
            dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=DT, dx=DX, dy=DX)
            job_id = api.start_reconstruction(dataset_id=dataset_id, method="toy")
            api.wait(job_id, timeout=HANG_S)
            job = http_json(srv, f"/api/jobs/{job_id}")
            api.download_volume(job_id, tmp_path / "served.h5")
            text = api.export(job_id, "toy-text", tmp_path / "served.txt")
            npz = api.export(job_id, "npz", tmp_path / "served.npz")
        log = srv.log.read_text()
    finally:
        srv.stop()
    assert job["state"] == "succeeded", job
    assert job["params"]["method"] == "toy"
    assert job["params"]["result"]["params_used"]["method"] == "toy", job["params"]["result"]
    with h5py.File(tmp_path / "served.h5", "r") as f:
        assert f.attrs["method"] == "toy" and json.loads(f.attrs["params"])["method"] == "toy"
    assert text.read_text() == f"method=toy\nshape={N_T}x{N}x{N}\n"
    with np.load(npz) as got:
        assert str(got["method"]) == "toy"
    # the broken plugin left the server up, and was named in its log
    assert "'broken'" in log and "fpscan_broken" in log


def http_json(srv: Server, path: str) -> dict:
    with srv.client() as http:
        r = http.get(path)
        r.raise_for_status()
        return r.json()
