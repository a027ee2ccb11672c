"""Plugins and the record of the method that ran.

A tiny third-party distribution, written here into a temporary ``sys.path`` folder as an
installer would (its package and its ``.dist-info`` with ``METADATA`` and ``entry_points.txt``;
no network, nothing inside fpscan touched), declares a method ``toy`` (NEDNER's algorithm
registered under another name), a method ``toy-bare`` (NEDNER's algorithm declaring no memory or
work model) and an export format ``toy-text``, each built from the plugin API ``fpscan.plugins``.
A second one declares a method whose module does not exist. With that folder on ``PYTHONPATH``:

- the library (``fpscan.METHODS``, ``fpscan.export_formats``) and the CLI's help offer them, each
  list in its registry's order (``Method.order``, ``Format.rank``; other installed plugins may
  sit anywhere in it), and the broken plugin is reported once, by name, on stderr;
- the admission judges ``toy-bare`` by the conservative rules for a method that declares no
  model (``fpscan.plugins.undeclared_peak`` / ``undeclared_work``), never by NEDNER's figures;
- a real ``fpscan serve`` (uvicorn on 127.0.0.1) starts and lists them in ``GET
  /api/reconstructions/methods`` and ``GET /api/formats``; a job run with ``toy`` records
  ``toy`` in the job, in its ``params_used``, in ``volume.h5`` and in its exports (the plugin's
  ``toy-text`` and the built-in ``npz``).

Oracles: the entry points written here, the rules' own formulas, and the files read back with
h5py / numpy.
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
"""Third-party methods: NEDNER's algorithm under the name ``toy``, and again as ``toy-bare``,
a method that declares no memory or work model."""
from dataclasses import replace

from fpscan.plugins import Method
from fpscan.service.recon.methods.nedner import METHOD as NEDNER

METHOD = replace(NEDNER, name="toy", title="toy (NEDNER under another name)", order=900, default_for=())
BARE = Method(name="toy-bare", title="toy without models", needs_grid=False, options_model=NEDNER.options_model,
              run=NEDNER.run, order=950)
'''

FORMAT_PY = '''
"""A third-party export format: a result's method and p0 shape as text."""
from pathlib import Path

from fpscan.plugins import Format


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
        toy-bare = fpscan_toy.method:BARE

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
from fpscan.plugins import Method, register_method, undeclared_peak, undeclared_work
from fpscan.service import plugins
from fpscan.service.formats import FORMATS
from fpscan.service.jobs.admission import estimate_memory, estimate_work
plugins.load_group("fpscan.methods", Method, register_method)  # loading again reports nothing again
methods = list(fpscan.METHODS)
exports = list(fpscan.export_formats())
# a 256 x 64 x 64 float32 grid: the admission's figures for each method
shape = {"n_t": 256, "n_x": 64, "n_y": 64, "input_itemsize": 4}
admitted = {name: [estimate_memory(shape, {"method": name}), estimate_work(shape, {"method": name})]
            for name in ("toy-bare", "toy", "nedner", "ner")}
print(json.dumps({"methods": methods, "orders": [fpscan.METHODS[m].order for m in methods],
                  "exports": exports, "ranks": [FORMATS[f].rank for f in exports],
                  "failures": plugins.failures(), "admitted": admitted,
                  "rules": [undeclared_peak(256, 64, 64, n_z=256), undeclared_work(256, 64, 64, n_z=256)]}))
'''


def _in_order(names: list, positions: list, name: str, position: int) -> None:
    """``names`` is sorted by ``positions`` and ``name`` sits where ``position`` puts it: after
    every entry of a smaller position, before every entry of a larger one."""
    assert positions == sorted(positions), list(zip(names, positions))
    k = names.index(name)
    assert positions[k] == position
    assert all(p <= position for p in positions[:k]) and all(p >= position for p in positions[k + 1:]), \
        list(zip(names, positions))


def test_a_plugin_reaches_the_library_and_the_cli_and_a_broken_one_is_reported_once(site):
    out = subprocess.run([sys.executable, "-c", LIBRARY], capture_output=True, text=True, timeout=120, env=_env(site))
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert {"toy", "toy-bare", "nedner", "ner"} <= set(got["methods"]) and "broken" not in got["methods"]
    _in_order(got["methods"], got["orders"], "toy", 900)
    _in_order(got["methods"], got["orders"], "toy-bare", 950)
    assert "toy-text" in got["exports"] and "npz" in got["exports"]
    _in_order(got["exports"], got["ranks"], "toy-text", 1000)
    # this test's broken plugin is reported (another installed one may be too); its good one is not
    assert "ModuleNotFoundError" in got["failures"]["fpscan.methods:broken (fpscan_broken)"]
    assert not [key for key in got["failures"] if "fpscan_toy" in key], got["failures"]
    assert out.stderr.count("'broken'") == 1, out.stderr

    # the admission: toy-bare by the conservative rules (its input is in the working precision,
    # so the rule's figure is the whole estimate), toy by NEDNER's own models, never the reverse
    (bare_memory, bare_work), (toy_memory, toy_work) = got["admitted"]["toy-bare"], got["admitted"]["toy"]
    assert [bare_memory, bare_work] == got["rules"]
    assert [toy_memory, toy_work] == got["admitted"]["nedner"]
    assert bare_memory > max(got["admitted"]["nedner"][0], got["admitted"]["ner"][0])
    assert bare_memory == 32 * 8 * 256 * 64 * 64 + 256 * 2**20  # 32 float64 copies of the input, + 256 MiB
    assert bare_work == pytest.approx(5e-8 * 64 * 64 * 256 * 64 * 64)  # 50 ns per sensor and voxel

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
            assert {"toy", "toy-bare"} <= set(methods) and "broken" not in methods
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
    rows = int(1500.0 * (N_T - 1) * DT / DX) + 1  # the default depth grid: the pitch down to c·t_last (19 rows)
    assert text.read_text() == f"method=toy\nshape={rows}x{N}x{N}\n"
    with np.load(npz) as got:
        assert str(got["method"]) == "toy"
    # the broken plugin left the server up, and was named in its log
    assert "'broken'" in log and "fpscan_broken" in log


def http_json(srv: Server, path: str) -> dict:
    with srv.client() as http:
        r = http.get(path)
        r.raise_for_status()
        return r.json()
