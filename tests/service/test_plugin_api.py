"""The public plugin API ``fpscan.plugins`` (docs/plugins.md).

- every name of its ``__all__`` exists, is the object fpscan itself uses, is documented (a
  docstring of its own for a class or function) and is named in docs/plugins.md;
  ``API_VERSION`` is ``"major.minor"``;
- the entry points of other packages are read lazily: importing fpscan's method registry imports
  no plugin module; the first read of the registry does (a real distribution in a temporary
  ``sys.path`` folder, in a fresh interpreter);
- a method registered with ``register_method`` reaches ``fpscan.reconstruct``: its own option is
  validated there (a bad value is a ValueError naming the option), its ``run`` gets the options
  instance and reports progress, and the admission judges it, declaring no model, by the
  conservative rules whose numbers the docs state.

Oracles: the documented contract (the names, the rules' formulas), ``sys.modules`` and the toy
method's own arithmetic; nothing of fpscan is mocked.
"""
from __future__ import annotations

import inspect
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pydantic import Field

import fpscan
import fpscan.plugins as api

REPO = Path(__file__).resolve().parents[2]


def test_every_public_name_exists_and_is_documented():
    doc = (REPO / "docs" / "plugins.md").read_text(encoding="utf-8")
    assert len(api.__all__) == len(set(api.__all__)) >= 20
    for name in api.__all__:
        obj = getattr(api, name)  # an AttributeError names a missing one
        if inspect.isclass(obj) or inspect.isfunction(obj):
            own = obj.__dict__.get("__doc__") if inspect.isclass(obj) else obj.__doc__
            # a dataclass without a docstring gets "Name(field, ...)" written for it
            assert own and own.strip() and not own.startswith(f"{name}("), f"{name} has no docstring of its own"
        assert re.search(rf"\b{re.escape(name)}\b", doc), f"docs/plugins.md does not name fpscan.plugins.{name}"
    assert api.__doc__ and "API_VERSION" in api.__doc__


def test_the_public_names_are_the_objects_fpscan_uses():
    from fpscan.service import formats
    from fpscan.service.recon import methods

    assert api.Method is methods.Method and api.register_method is methods.register
    assert api.MethodOptions is methods.MethodOptions
    assert api.Format is formats.Format and api.register_format is formats.register
    assert api.GridDataset is fpscan.GridDataset and api.PointDataset is fpscan.PointDataset
    assert api.Reconstruction is fpscan.Reconstruction
    assert issubclass(api.OptionError, ValueError)


def test_api_version_is_major_minor():
    assert re.fullmatch(r"\d+\.\d+", api.API_VERSION), api.API_VERSION
    assert int(api.API_VERSION.split(".")[0]) >= 1


def test_the_conservative_rules_have_their_documented_numbers():
    """32 float64 copies of the larger of input and output, plus 256 MiB; 50 ns per sensor and
    voxel in float32, FLOAT64_WORK times that in float64."""
    mib = 2**20
    assert api.undeclared_peak(256, 64, 64) == 32 * 8 * 256 * 64 * 64 + 256 * mib
    # the output is the larger: 512 rows upsampled 2x laterally
    assert api.undeclared_peak(256, 64, 64, n_z=512, upsample=2) == 32 * 8 * 512 * 128 * 128 + 256 * mib
    # point data: n_points sensors in, the full lattice out
    assert api.undeclared_peak(256, 64, 64, n_points=100) == 32 * 8 * 256 * 64 * 64 + 256 * mib
    assert api.undeclared_work(256, 64, 64) == pytest.approx(5e-8 * 4096 * 256 * 4096)
    assert api.undeclared_work(256, 64, 64, n_points=100, dtype="float64") == pytest.approx(
        5e-8 * 100 * 256 * 4096 * api.FLOAT64_WORK)


PROBE_PY = '''
"""A method plugin whose import is visible in sys.modules."""
from fpscan.plugins import Method, MethodOptions


class ProbeOptions(MethodOptions):
    """No options of its own."""


def run(ds, sound_speed, options, progress):
    raise NotImplementedError


METHOD = Method(name="lazy-probe", title="a probe", needs_grid=True, options_model=ProbeOptions, run=run,
                order=5000)
'''

LAZY = r'''
import json
import sys

import fpscan.plugins
import fpscan.service.formats
import fpscan.service.recon.methods as methods

seen = {"after_import": "fpscan_lazy_probe" in sys.modules, "loaded_flag": methods.METHODS.loaded}
names = list(methods.METHODS)
seen.update(after_read="fpscan_lazy_probe" in sys.modules, listed="lazy-probe" in names,
            loaded=methods.METHODS.loaded)
print(json.dumps(seen))
'''


def _run_with_plugin(tmp_path, package: str, module: str, entry_points: str, script: str) -> dict:
    """``script`` run in a fresh interpreter beside a distribution ``package`` (its one module
    and a ``.dist-info`` with ``entry_points``, as an installer writes them): its last line as JSON."""
    site = tmp_path / "site"
    (site / package).mkdir(parents=True)
    (site / package / "__init__.py").write_text(textwrap.dedent(module))
    info = site / f"{package}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(entry_points)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])])}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_plugin_entry_points_are_read_on_the_registrys_first_read(tmp_path):
    seen = _run_with_plugin(tmp_path, "fpscan_lazy_probe", PROBE_PY,
                            "[fpscan.methods]\nlazy-probe = fpscan_lazy_probe:METHOD\n", LAZY)
    assert seen == {"after_import": False, "loaded_flag": False, "after_read": True, "listed": True,
                    "loaded": True}, seen


BOTH_PY = '''
"""A plugin module with a method and a format that reads the methods' registry while imported."""
from dataclasses import replace

import fpscan.service.recon.methods as methods
from fpscan.plugins import Format

NEDNER = methods.METHODS["nedner"]  # a registry read during the import
METHOD = replace(NEDNER, name="both-method", title="both", order=5001, default_for=())
FORMAT = Format(name="both-text", title="both", container="file", export_from="result",
                export=lambda src, out: out, suffix=".txt", media_type="text/plain")
'''

BOTH = r'''
import json

import fpscan.service.formats as formats
import fpscan.service.plugins as plugins
import fpscan.service.recon.methods as methods

listed_formats = list(formats.FORMATS)  # the formats load first: the module reads the methods meanwhile
print(json.dumps({"format": "both-text" in listed_formats, "method": "both-method" in list(methods.METHODS),
                  "failures": plugins.failures()}))
'''


def test_a_plugin_module_that_reads_the_other_registry_while_imported_loads_whole(tmp_path):
    """Its format's group loads first; its import reads the methods' registry, whose load names the
    same (half-imported) module: that entry point is registered once the module is imported."""
    seen = _run_with_plugin(tmp_path, "fpscan_both", BOTH_PY, "[fpscan.methods]\nboth-method = fpscan_both:METHOD\n\n"
                            "[fpscan.formats]\nboth-text = fpscan_both:FORMAT\n", BOTH)
    assert seen == {"format": True, "method": True, "failures": {}}, seen


class GainOptions(api.MethodOptions):
    """Options of the toy method: a gain."""

    gain: float = Field(1.0, gt=0, le=100, description="a factor on the image", json_schema_extra={"unit": "1"})


def _run(ds, sound_speed, options, progress):
    """The envelope of the A-lines times the gain, on depth rows c·dt."""
    assert isinstance(options, GainOptions)
    progress(0.5, "toy")
    n_t, n_x = ds.data.shape
    z = np.arange(n_t) * sound_speed * ds.dt
    x = (np.arange(n_x) - (n_x - 1) / 2) * ds.dx
    return api.Reconstruction(options.gain * np.abs(ds.data), z, x, None, {"gain": options.gain,
                                                                          "sound_speed": sound_speed})


@pytest.fixture
def toy():
    method = api.register_method(api.Method(name="toy-api-gain", title="a toy gain", needs_grid=True,
                                            options_model=GainOptions, run=_run, order=5000))
    try:
        yield method
    finally:
        del fpscan.METHODS["toy-api-gain"]


def test_a_registered_method_reaches_reconstruct_with_its_own_option_checked(toy):
    data = np.zeros((16, 4))
    data[5] = -2.0
    ds = fpscan.GridDataset(data, dx=1e-4, dt=2e-8, sound_speed=1500.0)
    seen = []
    rec = fpscan.reconstruct(ds, "toy-api-gain", gain=3, progress=lambda f, stage: seen.append((f, stage)))
    assert float(rec.p0.max()) == 6.0 and int(rec.p0[:, 0].argmax()) == 5
    assert rec.params["method"] == "toy-api-gain" and rec.params["gain"] == 3.0
    assert rec.z[1] == pytest.approx(1500.0 * 2e-8)
    assert ("toy" in {stage for _, stage in seen}) and seen[-1][0] == 1.0
    assert fpscan.reconstruct(ds, "toy-api-gain", {"gain": "2.5"}).params["gain"] == 2.5  # text is parsed

    for bad in (0, -1, 101, float("nan")):
        with pytest.raises(ValueError, match="gain"):
            fpscan.reconstruct(ds, "toy-api-gain", gain=bad)
    with pytest.raises(api.OptionError, match=r"takes no option eps \(its options: .*gain"):
        fpscan.reconstruct(ds, "toy-api-gain", eps=1e-6)  # nedner's option, not this one's
    with pytest.raises(ValueError, match="unknown option frobnicate"):
        fpscan.reconstruct(ds, "toy-api-gain", frobnicate=1)
    assert toy.options[-1] == "gain" and toy.defaults["gain"] == 1.0


def test_a_method_without_models_is_admitted_by_the_conservative_rules(toy):
    from fpscan.service.jobs.admission import estimate_memory, estimate_work

    assert toy.peak_memory is None and toy.work is None
    shape = {"n_t": 256, "n_x": 64, "n_y": 64, "input_itemsize": 4}  # float32 input: no separate copy
    assert estimate_memory(shape, {"method": "toy-api-gain"}) == api.undeclared_peak(256, 64, 64, n_z=256)
    assert estimate_work(shape, {"method": "toy-api-gain"}) == pytest.approx(api.undeclared_work(256, 64, 64))
    # not NEDNER's or NER's figures
    for builtin in ("nedner", "ner"):
        assert estimate_memory(shape, {"method": builtin}) < estimate_memory(shape, {"method": "toy-api-gain"})
        assert estimate_work(shape, {"method": builtin}) < estimate_work(shape, {"method": "toy-api-gain"})
