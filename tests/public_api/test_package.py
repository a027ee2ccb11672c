"""The public package ``import fpscan``: one flat namespace, lazy, documented
with Examples that run."""
from __future__ import annotations

import doctest
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def test_the_examples_run():
    """The Examples of fpscan/__init__.py run as doctests (a plan's mask, a reconstruction
    whose ball lands in its quadrant, a result folder, an OME-Zarr export)."""
    import fpscan

    result = doctest.testmod(fpscan, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 10 and result.failed == 0, result


def test_import_is_light():
    """``import fpscan`` loads none of the scientific stack, the service or the client."""
    code = ("import sys, fpscan; heavy = {'numpy', 'scipy', 'h5py', 'matplotlib', 'httpx', 'fpscan.service', "
            "'fpscan.driver', 'fpscan.clients', 'fpscan.physics'} & set(sys.modules); print(sorted(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


def test_every_public_name_is_its_owners_object():
    import fpscan
    import fpscan.clients.http
    import fpscan.driver.scanfile
    import fpscan.service.formats
    import fpscan.service.pipeline
    import fpscan.service.plans

    assert set(fpscan.__all__) == set(fpscan._EXPORTS) | set(fpscan._RENAMED) | {"__version__"}
    for name in fpscan.__all__:
        assert getattr(fpscan, name) is not None, name
        assert name in dir(fpscan)
    assert fpscan.reconstruct is fpscan.service.pipeline.reconstruct  # the one dispatch
    assert fpscan.Client is fpscan.clients.http.Client and fpscan.AsyncClient is fpscan.clients.http.AsyncClient
    assert fpscan.read_scan is fpscan.driver.scanfile.read_scan
    assert fpscan.make_plan is fpscan.service.plans.make_plan
    assert fpscan.export_file is fpscan.service.formats.export_file
    assert set(fpscan.METHODS) >= {"nedner", "ner", "linear", "nearest", "cubic", "kwave", "tv"}
    from fpscan.service.formats.ipasc import export_scan

    assert fpscan.export_ipasc is export_scan
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert fpscan.__version__ in (meta["project"]["version"], "0+unknown")
    with pytest.raises(AttributeError, match="no attribute 'reconstruct_grid'"):
        fpscan.reconstruct_grid  # noqa: B018 -- the methods are reached through reconstruct


def test_packaging_keeps_the_console_script_and_ships_fpscan():
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert meta["project"]["scripts"] == {"fpscan": "fpscan.clients.cli:main"}
    assert meta["tool"]["setuptools"]["packages"]["find"]["include"] == ["fpscan", "fpscan.*"]  # one import root
    assert any(d.startswith("ome-zarr") for d in meta["project"]["optional-dependencies"]["driver"])
