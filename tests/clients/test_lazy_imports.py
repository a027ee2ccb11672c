"""The command line answers at once: what a fresh interpreter imports for
``fpscan --version`` / ``--help``, ``import fpscan.service.recon`` and a first reconstruction."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

# loaded by the subcommands and the reconstruction, never by the answers that need none of them
HEAVY = ("numpy", "h5py", "scipy", "numba", "finufft", "pydantic", "httpx", "fpscan.service", "fpscan.experiments",
         "matplotlib")


def _fresh(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


CLI = r'''
import contextlib, io, json, sys
from fpscan.clients.cli import main
buf = io.StringIO()
with contextlib.redirect_stdout(buf):
    try:
        main({argv!r})
    except SystemExit as exc:
        code = exc.code
print(json.dumps({{"code": code, "stdout": buf.getvalue(), "modules": sorted(sys.modules)}}))
'''


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["-h"]])
def test_version_and_help_import_no_heavy_module(argv):
    got = _fresh(CLI.format(argv=argv))
    assert got["code"] == 0
    loaded = [m for m in got["modules"] if m.split(".")[0] in HEAVY or ".".join(m.split(".")[:2]) in HEAVY]
    assert loaded == [], loaded
    if argv == ["--version"]:
        from fpscan.driver.acquire import software_version

        assert got["stdout"] == f"fpscan {software_version()}\n"
    else:  # every subcommand is listed with its one-line help
        from fpscan.clients.cli import subcommand_modules

        for module in subcommand_modules():
            assert module.COMMAND in got["stdout"] and module.HELP.split()[0] in got["stdout"], module.COMMAND


def test_subcommand_help_lists_its_options():
    """``fpscan recon --help`` still shows recon's options (its module is set up when named)."""
    got = _fresh(CLI.format(argv=["recon", "--help"]))
    assert got["code"] == 0
    assert got["stdout"].startswith("usage: fpscan recon") and "--method" in got["stdout"], got["stdout"][:2000]


@pytest.mark.parametrize("columns", ["50", "120", "", "junk"])
def test_help_width_follows_shutils_rule(columns):
    """``fpscan --help`` wraps at the width argparse's own formatter (`shutil.get_terminal_size`)
    picks for the same ``$COLUMNS`` (unset, or not a number: stdout is a pipe here, so 80)."""
    code = r'''
import argparse, json
from fpscan.clients.cli import build_parser
ours = build_parser(())
stdlib = build_parser(())
stdlib.formatter_class = argparse.HelpFormatter
print(json.dumps({"ours": ours.format_help(), "stdlib": stdlib.format_help()}))
'''
    import os

    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    if columns:
        env["COLUMNS"] = columns
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout)
    assert got["ours"] == got["stdlib"]
    width = int(columns) if columns.isdigit() else 80
    assert max(map(len, got["ours"].splitlines())) <= width - 2
    assert max(map(len, got["ours"].splitlines())) > width - 20  # wrapped at that width, not narrower


def test_version_matches_the_installed_metadata():
    from importlib.metadata import PackageNotFoundError, version

    from fpscan.driver.acquire import software_version

    try:
        expected = version("fpscan")
    except PackageNotFoundError:
        expected = "0+unknown"
    assert software_version() == expected


RECON = r'''
import json, sys
import fpscan.service.recon
light = sorted(sys.modules)
from fpscan.service.recon import reconstruct_grid, reconstruct_points
import numpy as np
data = np.zeros((32, 8, 8), dtype=np.float32)
data[3, 2, 2] = 1.0
tiny = reconstruct_grid(data, 1e-4, 2e-8, dz=3e-5)  # n_t rows of c dt
rng = np.random.default_rng(0)
pos = rng.uniform(0.0, 7e-4, (40, 2))
reconstruct_points(rng.standard_normal((40, 32)), pos, 2e-8, weights=np.full(40, 1e-8),
                   grid=(np.arange(8) * 1e-4, np.arange(8) * 1e-4))
after_tiny = sorted(sys.modules)
rec = reconstruct_grid(np.zeros((64, 48, 48)), 1e-4, 2e-8, dz=3e-5)
print(json.dumps({"light": light, "tiny": after_tiny, "after": sorted(sys.modules),
                  "shape": [list(tiny.p0.shape), list(rec.p0.shape)]}))
'''


def test_import_service_recon_loads_no_transform_library():
    """``import fpscan.service.recon`` loads numpy only; a small NER and NEDNER (32 x 8 x 8, 40
    A-lines) run in numpy and finufft (`fpscan.physics.fft_engine`: no scipy, no numba,
    whose imports and cache load cost a fresh interpreter about 1.5 s); a larger one brings
    scipy.fft and numba; pylops/pyproximal never come with a direct reconstruction."""
    got = _fresh(RECON)
    for name in ("scipy", "numba", "finufft", "pylops", "pyproximal", "h5py"):
        assert name not in got["light"], name
    tiny = {m.split(".")[0] for m in got["tiny"]}
    assert "scipy" not in tiny and "numba" not in tiny and "llvmlite" not in tiny, sorted(tiny)
    assert "scipy.fft" in got["after"] and "numba" in got["after"]
    assert "pylops" not in got["after"] and "pyproximal" not in got["after"]
    assert got["shape"] == [[32, 8, 8], [64, 48, 48]]


def test_warmup_command_options_and_bad_dtype(capsys):
    from fpscan.clients.cli import main
    from fpscan.service.recon.warmup import warm_up

    with pytest.raises(SystemExit) as exit_:
        main(["warmup", "--help"])
    assert exit_.value.code == 0 and "--dtype" in capsys.readouterr().out
    # --quick (scripts/demo.sh's set-up): the methods a job worker warms before its first job, not tv
    from fpscan.service.recon.methods import METHODS

    assert main(["warmup", "--quick", "--dtype", "float32"]) == 0
    said = capsys.readouterr().out
    quick = [m.name for m in METHODS.values() if m.warm_up and not m.warm_in_background]
    assert said.startswith(f"compiled the kernels of {', '.join(quick)} in "), said
    assert "tv" not in said.split(" in ")[0], said
    with pytest.raises(SystemExit) as exit_:
        main(["warmup", "--dtype", "float16"])  # argparse's choices: a usage error
    assert exit_.value.code == 2 and "invalid choice" in capsys.readouterr().err
    with pytest.raises(ValueError, match="dtype must be one of"):
        warm_up(["float16"])


def test_job_worker_warms_the_quick_methods_first():
    """The methods a job worker warms before it takes a job (``warm_up(background=False)``: those
    whose ``Method.warm_in_background`` is false, the planar inversions and the k-Wave modes)
    never import the model-based operator and its pylops (the slowest import, warmed in a
    background thread) nor scipy.interpolate (only the k-Wave ``*cubic`` mode's); they report
    the cache of the kernels they warmed. Every method with a warm-up is in one of the two
    sets; unknown methods are a ValueError."""
    from fpscan.service.recon.methods import METHODS
    from fpscan.service.recon.warmup import cache_dirs, warm_up

    quick = {m.name for m in METHODS.values() if m.warm_up and not m.warm_in_background}
    slow = {m.name for m in METHODS.values() if m.warm_up and m.warm_in_background}
    assert quick and slow and not quick & slow
    with pytest.raises(ValueError, match="method must be one of"):
        warm_up(["float32"], methods=["nope"])
    with pytest.raises(ValueError, match="method must be one of"):
        cache_dirs(["nope"])
    got = _fresh(r'''
import json, sys
from fpscan.service.recon.warmup import warm_up
out = warm_up(["float32"], background=False)
print(json.dumps({"operator": "fpscan.service.recon.operator" in sys.modules, "pylops": "pylops" in sys.modules,
                  "kwave": "fpscan.service.recon.kwave" in sys.modules, "interpolate": "scipy.interpolate" in sys.modules,
                  "methods": out["methods"], "dirs": out["cache_dirs"]}))
''')
    assert set(got.pop("methods")) == quick
    dirs = got.pop("dirs")
    assert got == {"operator": False, "pylops": False, "kwave": True, "interpolate": False}, got
    assert dirs and set(dirs) <= set(cache_dirs()), (dirs, cache_dirs())


def test_serve_spawns_its_workers_before_the_heavy_imports():
    """``fpscan serve``'s command line (its options and their help, which states the default
    precision) is parsed without numpy, pydantic or the method registry: the job workers
    spawn, and start warming up, before the server's own imports."""
    got = _fresh(CLI.format(argv=["serve", "--help"]))
    assert got["code"] == 0
    from fpscan.service.recon.limits import DEFAULT_DTYPE

    assert f"reconstructions are {DEFAULT_DTYPE}" in got["stdout"]
    heavy = [m for m in got["modules"] if m.split(".")[0] in ("numpy", "pydantic", "scipy", "fastapi")
             or m in ("fpscan.service.pipeline", "fpscan.service.recon.methods", "fpscan.service.settings")]
    assert heavy == [], heavy


ADMIT = r'''
import json, sys
from fpscan.service.jobs.admission import estimate_memory
grid = {"kind": "grid", "n_t": 256, "n_y": 64, "n_x": 64, "dx": 6e-5, "dt": 8e-9, "c": 1500.0}
points = {**grid, "kind": "points", "n_points": 500}
sizes = {m: estimate_memory(points if m == "nedner" else grid, {"method": m})
         for m in ("ner", "nedner", "linear", "nearest", "cubic", "kwave", "tv")}
print(json.dumps({"sizes": sizes, "modules": sorted(sys.modules)}))
'''


def test_admitting_a_job_loads_no_transform_library():
    """The server admits a reconstruction (its memory model, on the request's path)
    without loading numba or scipy.fft: the first POST /api/reconstructions after start-up
    took 0.8-0.9 s while they loaded, against 6-50 ms once the model sized its grids from
    ``fpscan.physics.grid_sizes``."""
    got = _fresh(ADMIT)
    assert all(v > 0 for v in got["sizes"].values()), got["sizes"]
    assert got["sizes"]["tv"] > got["sizes"]["ner"]
    loaded = [m for m in got["modules"] if m.split(".")[0] in ("numba", "finufft", "pylops", "llvmlite")
              or m.startswith("scipy.fft") or m in ("fpscan.physics.nufft", "fpscan.physics.nufft_kernels")]
    assert loaded == [], loaded


WRITE = r'''
import json, os, sys, tempfile
import numpy as np
from fpscan.service.recon import reconstruct_grid
from fpscan.service.storage.results import write_result
data = np.zeros((32, 8, 8), dtype=np.float32)
data[5, 4, 4] = 1.0
with tempfile.TemporaryDirectory() as tmp:
    write_result(os.path.join(tmp, "result"), reconstruct_grid(data, 1e-4, 2e-8), input_id="t")
    files = sorted(os.listdir(os.path.join(tmp, "result")))
print(json.dumps({"files": files, "modules": sorted(sys.modules)}))
'''


def test_a_small_reconstruction_and_its_result_load_no_scipy():
    """``fpscan recon`` of a small file: the reconstruction runs in numpy (above) and the
    result's MIP pictures need no image-quality measure (``fpscan.service.metrics`` loads each on
    use: its sharpness and fits import scipy.ndimage and scipy.optimize, 1.2 s of a fresh
    interpreter, which had made writing a tiny result take 1.05 s instead of 0.21 s)."""
    got = _fresh(WRITE)
    assert "volume.h5" in got["files"] and any(f.endswith(".png") for f in got["files"]), got["files"]
    loaded = [m for m in got["modules"] if m.split(".")[0] in ("scipy", "numba")]
    assert loaded == [], loaded


LOCAL_RECON = r'''
import json, os, sys, tempfile
import numpy as np
from fpscan.clients.cli import main
with tempfile.TemporaryDirectory() as tmp:
    data = np.zeros((32, 8, 8), dtype=np.float32)
    data[5, 4, 4] = 1.0
    np.save(os.path.join(tmp, "a.npy"), data)
    code = main(["recon", os.path.join(tmp, "a.npy"), "--dt", "2e-8", "--dx", "1e-4", "--out",
                 os.path.join(tmp, "out"), "--quiet"])
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
'''


def test_a_local_command_loads_no_http_client():
    """``fpscan recon`` of a local file never loads the HTTP client (``fpscan.clients.http`` and httpx,
    0.2 s of every local command's start): the commands' error handler
    (``fpscan.clients.cli.common.client_errors``) imports it only when an error reaches it."""
    got = _fresh(LOCAL_RECON)
    assert got["code"] == 0
    loaded = [m for m in got["modules"] if m.split(".")[0] in ("httpx", "httpcore") or m.startswith("fpscan.clients.http")]
    assert loaded == [], loaded
