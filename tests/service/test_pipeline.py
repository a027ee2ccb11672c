"""The one dispatch (`fpscan.service.pipeline`): its method vocabulary is the one every surface
offers (API schema, CLI, web page, docs), its contracts (progress, should_stop →
Cancelled, one default dtype, options) hold, and the k-Wave mode equals k-Wave's
functions called directly (the independent transcriptions in `fpscan.service.recon.kwave`,
themselves checked against k-Wave's data in tests/recon)."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from fpscan.service.pipeline import DEFAULT_DTYPE, METHODS, OPTIONS, Cancelled, reconstruct
from fpscan.service.recon.dataset import GridDataset, PointDataset

REPO = Path(__file__).resolve().parents[2]


def test_every_surface_offers_the_one_vocabulary(shared_api):
    from fpscan.clients.cli import recon as cli_recon

    openapi = shared_api.get("/openapi.json").json()
    schemas = openapi["components"]["schemas"]
    # the body: a union keyed on method, one variant per method with its own options model
    body = openapi["paths"]["/api/reconstructions"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    variants = [ref["$ref"].rsplit("/", 1)[1] for ref in body["oneOf"]]
    keyed = {schemas[v]["properties"]["method"].get("const"): schemas[v] for v in variants}
    assert list(keyed) == [*METHODS, None]
    for name, spec in METHODS.items():
        assert "method" in keyed[name]["required"]
        options = schemas[keyed[name]["properties"]["params"]["$ref"].rsplit("/", 1)[1]]
        assert set(options["properties"]) == set(spec.options)
    default = schemas["ReconRequestDefaultMethod"]  # optional: absent or null = pipeline.default_method
    assert "ReconRequestDefaultMethod" in variants and "method" not in default.get("required", [])
    assert [b.get("enum") for b in default["properties"]["method"]["anyOf"]] == [list(METHODS), None]
    # the listing the web page builds its method choices from (tests/web check the page)
    listed = shared_api.get("/api/reconstructions/methods").json()
    assert [m["name"] for m in listed] == list(METHODS)
    for m in listed:
        spec = METHODS[m["name"]]
        assert (m["title"], m["needs_grid"], m["source"]) == (spec.title, spec.needs_grid, spec.source)
        # the speed of sound (every method's, listed once), then the model's own options
        speed = ("sound_speed", "sound_speed_range", "force")
        assert [o["name"] for o in m["options"]] == ["sound_speed", *(o for o in spec.options if o not in speed)]
        assert {o["name"]: o["default"] for o in m["options"] if o["default"] is not None} == \
            {k: v for k, v in spec.defaults.items() if k not in speed}
    parser = argparse.ArgumentParser()
    cli_recon.add_arguments(parser)
    method_action = next(a for a in parser._actions if a.dest == "method")
    assert list(method_action.choices) == list(METHODS)
    # the API page points at the generated page (a new method is one file: no hand-kept list),
    # which names every method (test_method_registry checks it is the registry's rendering)
    assert "(methods.md)" in (REPO / "docs" / "api.md").read_text()
    methods_doc = (REPO / "docs" / "methods.md").read_text()
    assert all(f"`{name}`" in methods_doc for name in METHODS)
    help_text = parser.format_help()
    assert f"default {DEFAULT_DTYPE}" in help_text
    for m in METHODS.values():
        assert set(m.options) - {"force"} <= set(OPTIONS)


def _grid(ndim=3, seed=0):
    rng = np.random.default_rng(seed)
    shape = (24, 5, 6) if ndim == 3 else (24, 7)
    return GridDataset(data=rng.standard_normal(shape), dx=1e-4, dt=2e-8, sound_speed=1500.0,
                       dy=1e-4 if ndim == 3 else None)


@pytest.mark.parametrize("method", list(METHODS))
def test_progress_cancel_and_default_dtype(method):
    ds = _grid()
    seen = []
    rec = reconstruct(ds, method, progress=lambda f, stage: seen.append((f, stage)))
    assert rec.p0.dtype == np.dtype(DEFAULT_DTYPE) and rec.params["method"] == method
    fractions = [f for f, _ in seen]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0 and fractions == sorted(fractions)
    stages = {s for _, s in seen}
    if METHODS[method].iterative:  # an iterative method names its iterations
        assert any(s.startswith("iteration ") for s in stages)
    else:
        assert stages == {"reconstructing"}
    calls = []

    def stop_after_two():
        calls.append(1)
        return len(calls) > 2

    with pytest.raises(Cancelled):
        reconstruct(ds, method, should_stop=stop_after_two)


def test_kwave_mode_is_kwaves_functions():
    from fpscan.service.recon import kspace_line_recon, kspace_plane_recon

    d3, d2 = _grid(3), _grid(2)
    a = reconstruct(d3, "kwave", interp="*linear", dtype="float64", positivity=True)
    b = kspace_plane_recon(d3.data, d3.dy, d3.dx, d3.dt, d3.sound_speed, interp="*linear", pos_cond=True)
    np.testing.assert_array_equal(a.p0, b)
    assert a.p0.shape == (24, 5, 6) and a.y is not None and len(a.x) == 6
    np.testing.assert_allclose(a.z, np.arange(24) * 1500.0 * 2e-8)
    a2 = reconstruct(d2, "kwave", dtype="float64")
    np.testing.assert_array_equal(a2.p0, kspace_line_recon(d2.data, d2.dx, d2.dt, d2.sound_speed))
    with pytest.raises(ValueError, match="interp"):
        reconstruct(d3, "kwave", interp="spline")


def test_options_and_inputs_are_checked():
    ds = _grid()
    with pytest.raises(ValueError, match="method must be one of"):
        reconstruct(ds, "banana")
    with pytest.raises(ValueError, match="unknown option"):
        reconstruct(ds, "ner", epsilon=1e-3)
    with pytest.raises(ValueError, match="dtype"):
        reconstruct(ds, "ner", dtype="int16")
    # an option the method does not take is refused naming its options (never silently unused)
    with pytest.raises(ValueError, match=r"method 'linear' takes no option eps, interp \(its options: sound_speed, sound_speed_range, force, dtype"):
        reconstruct(ds, "linear", eps=1e-3, interp="linear")
    sparse = PointDataset(alines=ds.data.reshape(24, -1).T[::2], positions=ds.to_points().positions[::2],
                          weights=None, dt=ds.dt, sound_speed=ds.sound_speed, grid=ds.axes(),
                          indices=np.stack(np.meshgrid(np.arange(6), np.arange(5)), -1).reshape(-1, 2)[::2],
                          lattice={"n_x": 6, "n_y": 5, "pitch": 1e-4})
    with pytest.raises(ValueError, match="lattice point"):
        reconstruct(sparse, "ner")
    assert reconstruct(sparse, "nedner").p0.shape == (7, 5, 6)  # the pitch (0.1 mm) down to c·t_last = 0.69 mm


def test_full_lattice_points_reconstruct_as_the_grid():
    ds = _grid()
    idx = np.stack(np.meshgrid(np.arange(6), np.arange(5)), -1).reshape(-1, 2)
    order = np.random.default_rng(3).permutation(len(idx))  # any scan order
    pts = ds.to_points()
    full = PointDataset(alines=pts.alines[order], positions=pts.positions[order], weights=None, dt=ds.dt,
                        sound_speed=ds.sound_speed, grid=ds.axes(), indices=idx[order], lattice={"n_x": 6, "n_y": 5, "pitch": 1e-4})
    assert full.full_lattice
    for method in ("ner", "cubic", "kwave"):
        np.testing.assert_array_equal(reconstruct(full, method).p0, reconstruct(ds, method).p0)


def test_a_methods_own_defaults_apply_unless_given():
    """``Method.defaults`` (tv: positivity on) fill only the options the caller left unset;
    an option whose rule differs from another method's option of the same name is refused at
    registration (one rule per option name), and so is a model that is no MethodOptions."""
    from pydantic import Field

    from fpscan.service.pipeline import Method, register
    from fpscan.service.recon.methods import MethodOptions

    tv = next((m for m in METHODS.values() if m.defaults.get("positivity")), None)
    if tv is None:
        pytest.skip("no method with its own positivity default")
    ds = _grid(seed=4)
    on = reconstruct(ds, tv.name, max_iter=2)
    off = reconstruct(ds, tv.name, max_iter=2, positivity=False)
    assert on.params["positivity"] is True and off.params["positivity"] is False
    assert on.p0.min() >= 0 and off.p0.min() < 0
    np.testing.assert_array_equal(on.p0, reconstruct(ds, tv.name, max_iter=2, positivity=True).p0)
    class Other(MethodOptions):
        upsample: int = Field(1, ge=1, le=99)  # ner's upsample is 1..8

    with pytest.raises(ValueError, match="one rule per option name"):
        register(Method(name="x", title="x", needs_grid=False, options_model=Other, run=METHODS["ner"].run))
    with pytest.raises(ValueError, match="MethodOptions"):
        register(Method(name="x", title="x", needs_grid=False, options_model=dict, run=METHODS["ner"].run))
    assert "x" not in METHODS
