"""The method registry (``fpscan.service.recon.methods``): every option of every
method, with the boundary values its own schema states (just inside, just outside each
range; each choice and one that is none), is judged alike by the library
(``fpscan.service.pipeline.reconstruct``), the CLI (``fpscan recon`` on a real file) and HTTP
(``POST /api/reconstructions`` on a real uvicorn server). The cases are generated from the
registry, so an option added in a method's file is covered here without an edit; the
expected verdict comes from the stated range, not from the code that enforces it.

Also: the surfaces generated from the registry (each method's options model in the HTTP
request's union, the methods endpoint's
value schemas, the CLI flags, docs/methods.md) name the same options, and the speed of sound
is ``sound_speed`` / ``--sound-speed`` with ``c`` / ``--c`` still accepted.
"""
from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from fpscan.service.pipeline import Cancelled, reconstruct
from fpscan.service.recon import device
from fpscan.service.recon import methods as registry
from fpscan.service.recon.dataset import GridDataset
from tests.service.service_servers import needs_recon

REPO = Path(__file__).resolve().parents[2]
DT, DX, C = 2e-8, 1e-4, 1500.0
N_T, N = 8, 6
DATA = np.random.default_rng(5).standard_normal((N_T, N, N)).astype(np.float32)
#: keeps an accepted model-based run short (unless the option under test is one of them)
SHORT = {"tv": {"max_iter": 2, "time_limit": 30.0}}


def _boundaries(schema: dict) -> tuple[list, list]:
    """(values inside, values outside) of a value schema: its ends and just beyond them."""
    if "enum" in schema:
        return list(schema["enum"]), ["no-such-" + str(schema["enum"][0])]
    if schema.get("type") == "boolean":
        return [True, False], [2, "maybe"]
    lo = schema.get("minimum")
    ex = schema.get("exclusiveMinimum")
    hi = schema.get("maximum")
    integer = schema.get("type") == "integer"
    inside, outside = [], []
    if lo is not None:
        inside.append(lo)
        outside.append(lo - 1 if integer else (lo - abs(lo) * 1e-6 if lo else -1e-12))
    if ex is not None:
        inside.append(ex + 1 if integer else (ex * (1 + 1e-6) if ex else 0.05))
        outside.append(ex)
    if hi is not None:
        inside.append(hi)
        outside.append(hi + 1 if integer else hi * (1 + 1e-6))
    return inside, outside


def _cases() -> list[tuple[str, str, object, bool]]:
    """(method, option, value, inside) for every option of the registry, tried with the
    first method that takes it."""
    out = []
    for name in registry.option_fields():
        method = next(m for m in registry.METHODS.values() if name in m.options_model.model_fields)
        schema = next(o["schema"] for o in registry.option_schemas(method) if o["name"] == name)
        inside, outside = _boundaries(schema)
        assert inside and outside, (name, schema)  # every option states its range or choices
        if name == "device" and not device.cuda_devices():  # "cuda" is refused where no GPU is visible
            inside, outside = [v for v in inside if v != "cuda"], [*outside, "cuda"]
        out += [(method.name, name, v, True) for v in inside] + [(method.name, name, v, False) for v in outside]
    return out


def _options(method: str, name: str, value) -> dict:
    return {**{k: v for k, v in SHORT.get(method, {}).items() if k != name}, name: value}


def _library(method: str, options: dict, *, run: bool) -> str | None:
    """None when the library accepts (``run``: the whole reconstruction; else stopped at its
    first progress check, after every option is checked), else the refusal's message."""
    ds = GridDataset(data=DATA.copy(), dx=DX, dt=DT, sound_speed=C, dy=DX)
    try:
        rec = reconstruct(ds, method, should_stop=None if run else (lambda: True), **options)
    except Cancelled:
        return None
    except ValueError as exc:
        return str(exc)
    assert run and np.all(np.isfinite(rec.p0)), (method, options)
    return None


def _flag(name: str) -> str:
    schema = next(o["schema"] for m in registry.METHODS.values() for o in registry.option_schemas(m)
                  if o["name"] == name)
    return schema.get("flag") or "--" + name.replace("_", "-")


def _cli_args(options: dict) -> list[str] | None:
    """The flags for ``options``; None when the CLI cannot even say the value (a true/false
    flag takes no value: ``--x`` / ``--no-x``)."""
    args: list[str] = []
    for name, value in options.items():
        flag = _flag(name)
        if isinstance(value, bool):
            args.append(flag if value else "--no-" + flag[2:])
        elif name in ("positivity", "debias", "whole_record"):
            return None
        else:
            args += [flag, repr(value) if isinstance(value, float) else str(value)]
    return args


def _cli(argv: list[str]) -> int:
    from fpscan.clients.cli import main

    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


def _cli_door(argv: list[str]) -> int:
    """``fpscan recon``'s checks without the run: its parser (argparse's own refusals, exit
    2) and its early option check (``fpscan.clients.cli.recon.check_options_early``: exit 2)."""
    import argparse

    from fpscan.clients.cli import recon as cli_recon

    parser = argparse.ArgumentParser()
    cli_recon.add_arguments(parser)
    try:
        args = parser.parse_args(argv[1:])
        cli_recon.check_options_early(args.method, cli_recon._params(args))
    except SystemExit as exc:
        return int(exc.code or 0)
    except ValueError:
        return 2
    return 0


@needs_recon
def test_every_registry_option_boundary_is_judged_alike_by_library_cli_and_http(shared_server, tmp_path, capsys):
    npy = tmp_path / "d.npy"
    np.save(npy, DATA)
    buf = io.BytesIO()
    np.save(buf, DATA)
    cases = _cases()
    ran: set[str] = set()
    cli_ran: set[str] = set()
    with shared_server.client() as api:
        r = api.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(DX), "sound_speed": repr(C)},
                     files={"file": ("d.npy", buf.getvalue(), "application/octet-stream")})
        assert r.status_code == 201, r.text
        dataset_id = r.json()["dataset_id"]
        for k, (method, name, value, inside) in enumerate(cases):
            options = _options(method, name, value)
            case = (method, name, value)
            # one accepted value of each option runs the whole reconstruction through the library
            lib = _library(method, options, run=inside and name not in ran)
            if inside and lib is None:
                ran.add(name)
            http = api.post("/api/reconstructions", json={"dataset_id": dataset_id, "method": method,
                                                          "params": options})
            flags = _cli_args(options)
            code = None
            if flags is not None:
                argv = ["recon", str(npy), "--dt", repr(DT), "--dx", repr(DX), "--quiet", "--method", method,
                        "--out", str(tmp_path / f"out{k}"), *flags]
                # the CLI runs one accepted value of each option whole, checks the others at its door
                code = _cli(argv) if not inside or name not in cli_ran else _cli_door(argv)
                if inside:
                    cli_ran.add(name)
            err = capsys.readouterr().err
            if inside:
                assert lib is None, (case, lib)
                assert http.status_code == 202, (case, http.text)
                assert code in (None, 0), (case, err)
                api.post(f"/api/jobs/{http.json()['id']}/cancel")
                continue
            assert lib is not None and name in lib, (case, lib)
            assert http.status_code == 422 and name in http.json()["detail"], (case, http.text)
            assert code in (None, 2), (case, code, err)
            if code is not None:
                assert name.replace("_", "-") in err or name in err or _flag(name) in err, (case, err)
    assert ran == set(registry.option_fields()), ran  # every option ran once for real
    assert {n for _, n, _, _ in cases} == set(registry.option_fields())


@needs_recon
def test_eps_below_the_kernel_range_is_a_422_naming_the_range(shared_api):
    """``eps = 5e-15`` is refused at the door with the kernel's range."""
    r = shared_api.post("/api/reconstructions", json={"dataset_id": "0" * 32, "method": "ner",
                                                      "params": {"eps": 5e-15}})
    assert r.status_code == 422 and "eps must be in [1e-14, 1e-1]" in r.json()["detail"], r.text


def test_the_generated_surfaces_name_every_option_of_the_registry(shared_api):
    """Each method's options model in the HTTP request's union, the methods endpoint, the CLI
    flags of ``fpscan recon`` and ``unmix`` and docs/methods.md are generated from the
    registry: the same options, the same ranges."""
    import argparse

    from fpscan.clients.cli import recon as cli_recon
    from fpscan.clients.cli import unmix as cli_unmix

    openapi = shared_api.get("/openapi.json").json()
    schemas = openapi["components"]["schemas"]
    options = set(registry.option_fields())
    speed = {"sound_speed", "sound_speed_range", "force"}
    listed = shared_api.get("/api/reconstructions/methods").json()
    for m in listed:
        spec = registry.METHODS[m["name"]]
        variant = next(v for v in schemas.values() if v.get("properties", {}).get("method", {}).get("const") == m["name"])
        props = schemas[variant["properties"]["params"]["$ref"].rsplit("/", 1)[1]]["properties"]
        assert set(props) == set(spec.options_model.model_fields) and speed <= set(props)
        got = {o["name"]: o for o in m["options"]}
        assert set(got) == {"sound_speed", *(set(spec.options_model.model_fields) - speed)}
        for o in registry.option_schemas(spec):
            assert got[o["name"]]["value_schema"] == o["schema"] and got[o["name"]]["default"] == o["default"]
            http = next(b for b in props[o["name"]].get("anyOf", [props[o["name"]]]) if b.get("type") != "null")
            for bound in ("minimum", "maximum", "exclusiveMinimum", "enum"):
                assert http.get(bound) == o["schema"].get(bound), (o["name"], bound)
    for module in (cli_recon, cli_unmix):
        parser = argparse.ArgumentParser()
        module.add_arguments(parser)
        dests = {a.dest for a in parser._actions}
        assert options <= dests, (module.__name__, options - dests)
        strings = {s for a in parser._actions for s in a.option_strings}
        assert {"--sound-speed", "--c", "--sound-speed-range", "--c-range"} <= strings
    assert registry.docs_table() in (REPO / "docs" / "methods.md").read_text(), \
        "docs/methods.md is not the registry's rendering: run scripts/methods_doc.py"


@needs_recon
def test_sound_speed_and_its_deprecated_name_c_mean_the_same(shared_api, tmp_path, capsys):
    """HTTP ``sound_speed`` and ``c`` (deprecated) are one option; so are ``--sound-speed``
    and ``--c``: the same value is refused alike, an accepted one is the job's ``c``."""
    for key in ("sound_speed", "c"):
        r = shared_api.post("/api/reconstructions", json={"dataset_id": "0" * 32, "method": "ner",
                                                          "params": {key: 2500.0}})
        assert r.status_code == 422 and "2500" in r.json()["detail"], (key, r.text)
        r = shared_api.post("/api/reconstructions", json={"dataset_id": "0" * 32, "method": "ner",
                                                          "params": {key: 1480.0}})
        assert r.status_code == 404, (key, r.text)  # valid; no such dataset
    npy = tmp_path / "d.npy"
    np.save(npy, DATA)
    for flag in ("--sound-speed", "--c"):
        code = _cli(["recon", str(npy), "--dt", repr(DT), "--dx", repr(DX), "--quiet", "--method", "ner",
                     "--out", str(tmp_path / flag.strip("-")), flag, "2500"])
        assert code == 2 and "2500" in capsys.readouterr().err, flag
        code = _cli(["recon", str(npy), "--dt", repr(DT), "--dx", repr(DX), "--quiet", "--method", "ner",
                     "--out", str(tmp_path / flag.strip("-")), flag, "1480"])
        assert code == 0, capsys.readouterr().err
        h5py = pytest.importorskip("h5py")
        with h5py.File(tmp_path / flag.strip("-") / "volume.h5", "r") as f:
            z, used = f["z"][:], json.loads(f.attrs["params"])
        assert used["sound_speed"] == 1480.0, used
        # the rows reach c·t_last at that c: ⌊1480 · (N_T - 1) · DT / DX⌋ + 1 of the pitch
        assert len(z) == math.floor(1480.0 * (N_T - 1) * DT / DX) + 1 and math.isclose(z[1] - z[0], DX), z
