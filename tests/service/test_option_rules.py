"""One rule per reconstruction option, enforced at every door: each
option's boundary values, just inside and just outside, fed to the library
(``fpscan.service.pipeline.reconstruct``), the CLI (``fpscan recon``) and HTTP
(``POST /api/reconstructions`` on a real server): all three accept or refuse alike, and
refuse with the kernel rule's own words (``fpscan.service.recon.checks``). An option the chosen
method does not take is refused the same way, naming the method's options."""
from __future__ import annotations

import io

import numpy as np
import pytest

from fpscan.service.pipeline import Cancelled, reconstruct
from fpscan.service.recon.dataset import GridDataset
from tests.service.service_servers import needs_recon

DT, DX, C = 2e-8, 1e-4, 1500.0
N_T, N = 8, 6
DATA = np.random.default_rng(3).standard_normal((N_T, N, N)).astype(np.float32)

#: (method, option, CLI flag, values just inside the rule, values just outside). The
#: ``extra`` options keep an accepted run short (tv: a time limit).
BOUNDS = [
    ("ner", "eps", "--eps", [1e-14, 0.1], [5e-15, 1e-15, 0.1000001]),
    ("ner", "upsample", "--upsample", [1, 8], [0, 9]),
    ("ner", "n_z", "--n-z", [2, 65536], [1, 65537]),
    ("ner", "dz", "--dz", [1e-9, 0.1], [0.99e-9, 0.1000001]),
    ("tv", "lam", "--lam", [0.0, 1e30], [-1e-12, 1.000001e30]),
    ("tv", "max_iter", "--max-iter", [1, 100000], [0, 100001]),
    ("tv", "time_limit", "--time-limit", [0.05, 604800], [0, 604800.5]),
    ("nedner", "sound_speed", "--sound-speed", [1000.0, 2000.0], [999.9, 2000.1]),
    ("ner", "dtype", "--dtype", ["float32", "float64"], ["float16"]),
    ("kwave", "interp", "--interp", ["*nearest", "cubic"], ["spline"]),
]
EXTRA = {"tv": {"time_limit": 0.2, "max_iter": 2}}


def _cases():
    for method, name, flag, inside, outside in BOUNDS:
        for v in inside:
            yield method, name, flag, v, True
        for v in outside:
            yield method, name, flag, v, False


def _library(method: str, options: dict) -> str | None:
    """None when the library accepts the options (it stops at its first progress check:
    every option is checked before any work), else the refusal's message."""
    ds = GridDataset(data=DATA.copy(), dx=DX, dt=DT, sound_speed=C, dy=DX)
    try:
        reconstruct(ds, method, should_stop=lambda: True, **options)
    except Cancelled:
        return None
    except ValueError as exc:
        return str(exc)
    raise AssertionError("the reconstruction neither stopped nor refused")


def _cli(argv: list[str]) -> int:
    """``fpscan`` in this process: its exit status (argparse's own refusals included)."""
    from fpscan.clients.cli import main

    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


def _cli_args(method: str, options: dict, flags: dict) -> list[str]:
    args = ["--method", method]
    for name, value in options.items():
        args += [flags.get(name, "--" + name.replace("_", "-")), repr(value) if isinstance(value, float) else
                 str(value)]
    return args


@needs_recon
def test_every_option_boundary_is_judged_alike_by_library_cli_and_http(server, tmp_path, capsys):
    npy = tmp_path / "d.npy"
    np.save(npy, DATA)
    buf = io.BytesIO()
    np.save(buf, DATA)
    flags = {name: flag for _, name, flag, _, _ in BOUNDS}
    seen = []
    with server.client() as api:
        r = api.post("/api/datasets", data={"format": "npy", "dt": repr(DT), "dx": repr(DX), "sound_speed": repr(C)},
                     files={"file": ("d.npy", buf.getvalue(), "application/octet-stream")})
        assert r.status_code == 201, r.text
        dataset_id = r.json()["dataset_id"]
        for k, (method, name, _flag, value, inside) in enumerate(_cases()):
            options = {**EXTRA.get(method, {}), name: value}
            lib = _library(method, options)
            http = api.post("/api/reconstructions", json={"dataset_id": dataset_id, "method": method,
                                                          "params": options})
            code = _cli(["recon", str(npy), "--dt", repr(DT), "--dx", repr(DX), "--quiet",
                         "--out", str(tmp_path / f"out{k}"), *_cli_args(method, options, flags)])
            err = capsys.readouterr().err
            case = (method, name, value)
            seen.append(case)
            if inside:
                assert lib is None, (case, lib)
                assert http.status_code == 202, (case, http.text)
                assert code == 0, (case, err)
                api.post(f"/api/jobs/{http.json()['id']}/cancel")
                continue
            assert lib is not None, case
            assert http.status_code == 422, (case, http.text)
            assert code == 2, (case, code, err)
            if name in ("dtype", "interp"):  # argparse's own choices: named, not reworded
                assert name in http.json()["detail"] and name in lib and f"--{name}" in err, (case, err)
                continue
            # the kernel rule at every door (the range named), in each door's words: the command
            # line's flags (fpscan.clients.cli.in_flags); the request's JSON fields are the library's names
            from fpscan.clients.cli import in_flags

            rule = lib.split(", got")[0].removeprefix(f"{name}: ")
            assert rule in http.json()["detail"], (case, lib, http.json()["detail"])
            assert in_flags(rule, options=True) in err, (case, lib, err)
    assert {n for _, n, _ in seen} == {b[1] for b in BOUNDS}
    # the ranges are the kernel's: eps below its range is refused naming the range
    assert "eps must be in [1e-14, 1e-1]" in _library("ner", {"eps": 5e-15})


@needs_recon
@pytest.mark.parametrize(("method", "option", "flag", "value"), [
    ("nedner", "lam", "--lam", 1.0), ("ner", "max_iter", "--max-iter", 5), ("kwave", "eps", "--eps", 1e-6),
    ("tv", "upsample", "--upsample", 2), ("linear", "interp", "--interp", "cubic"),
])
def test_an_option_the_method_does_not_take_is_refused_naming_its_options(
        shared_server, tmp_path, capsys, method, option, flag, value):
    from fpscan.service.pipeline import METHODS

    its = ", ".join(METHODS[method].options)
    lib = _library(method, {option: value})
    assert lib is not None and f"takes no option {option}" in lib and its in lib, lib
    npy = tmp_path / "d.npy"
    np.save(npy, DATA)
    code = _cli(["recon", str(npy), "--dt", repr(DT), "--dx", repr(DX), "--quiet", "--out", str(tmp_path / "o"),
                 "--method", method, flag, str(value)])
    err = capsys.readouterr().err
    # each door in its own words: the command line's flags, the request's JSON fields
    from fpscan.clients.cli import in_flags

    assert code == 2 and f"takes no option {flag}" in err and in_flags(its, options=True) in err, (code, err)
    with shared_server.client() as api:
        r = api.post("/api/reconstructions", json={"dataset_id": "0" * 32, "method": method,
                                                   "params": {option: value}})
    detail = r.json()["detail"]
    assert r.status_code == 422 and f"takes no option {option}" in detail, r.text
    assert its in detail, r.text


@needs_recon
def test_thousands_of_names_no_method_takes_are_one_refusal(shared_server):
    """A body of 64 KiB can hold about 4000 option names no method takes. Each used to be a
    validation error of its own, about 17 ms of the server's event loop per request; they are one
    refusal now, which says how many, at the library's door and over HTTP alike."""
    import pydantic

    from fpscan.service.api.models import ReconRequest

    names = {f"opt{i}": i for i in range(3000)}  # within the 64 KiB a request body may have
    body = {"dataset_id": "0" * 32, "method": "ner", "params": names}
    with pytest.raises(pydantic.ValidationError) as refused:
        pydantic.TypeAdapter(ReconRequest).validate_python(body)
    assert refused.value.error_count() == 1, refused.value.error_count()
    lib = _library("ner", names)
    assert lib is not None and "'opt0', 'opt1', 'opt2', ...: 3000 names no method takes" in lib and len(lib) < 400, \
        (lib or "")[:400]
    with shared_server.client() as api:
        r = api.post("/api/reconstructions", json=body)
    assert r.status_code == 422 and "3000 names no method takes" in r.json()["detail"], r.text[:400]
    # a few names, one unknown among them: refused by its name, as before
    few = {"opt0": 1, "eps": 1e-6}
    assert "opt0" in (_library("ner", few) or ""), _library("ner", few)


@needs_recon
def test_a_refused_value_is_shown_in_a_few_of_its_elements():
    """The message names a refused value as reprlib shows it: a list of thousands by its first
    elements, a long text by its ends, so that a 64 KiB body refused for one option does not make a
    message of its size."""
    lib = _library("ner", {"n_z": [[1, 2]] * 10000})
    assert lib is not None and lib.endswith("got [[1, 2], [1, 2], [1, 2], [1, 2], ...]"), (lib or "")[:400]
    lib = _library("ner", {"eps": "1" * 60000})
    assert lib is not None and "eps must be in [1e-14, 1e-1], got '1111" in lib and "...1111" in lib, (lib or "")[:400]
    assert len(lib) < 200, len(lib)
