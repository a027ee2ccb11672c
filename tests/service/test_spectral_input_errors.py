"""Bad excitation-wavelength lists (out of 400-2000 nm, repeated, empty) end in a clear
error everywhere a user gives them: the plan and unmixing libraries (ValueError), the
CLI (`fpscan plan`, `fpscan unmix`: exit 1, one line naming the fault, nothing written)
and the API (POST /api/plans, /api/plans/preview, /api/reconstructions with unmix: 422
with the reason; real uvicorn). So do bad autofocus options (a ``sound_speed_range`` that is not
an interval or comes without ``c="auto"``)."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.clients.cli import main as fpscan_main
from fpscan.driver.plan import check_wavelengths
from fpscan.service.recon.unmix import unmix

LATTICE = {"n_x": 4, "n_y": 4, "pitch": 1e-4}
BAD = [  # (wavelengths in m, words the reason must hold)
    ([3.5e-7, 8.5e-7], "400 nm to 2000 nm"),
    ([7.5e-7, 2.1e-6], "400 nm to 2000 nm"),
    ([7.5e-7, 8.5e-7, 7.5e-7], "repeat"),
    ([], "at least one"),
]


@pytest.mark.parametrize("wavelengths, reason", BAD)
def test_library(wavelengths, reason):
    with pytest.raises(ValueError, match=reason):
        check_wavelengths(wavelengths)
    unmix_reason = {"repeat": "distinct", "at least one": "at least two wavelengths"}.get(reason, reason)
    with pytest.raises(ValueError, match=unmix_reason):
        unmix(np.ones((len(wavelengths), 3, 3)), wavelengths)


@pytest.mark.parametrize("wavelengths, reason", BAD[:3])
def test_cli_plan(tmp_path, capsys, wavelengths, reason):
    out = tmp_path / "plan.json"
    argv = ["plan", "full", "--n-x", "4", "--n-y", "4", "--pitch", "1e-4", "--out", str(out)]
    for w in wavelengths:
        argv += ["--wavelength", repr(w)]
    assert fpscan_main(argv) == 2  # refused input: a usage error
    err = capsys.readouterr().err.strip()
    assert err.startswith("fpscan plan: error: wavelengths: ") and reason in err, err
    assert "pydantic" not in err and len(err.splitlines()) == 1, err
    assert not out.exists()


@pytest.mark.parametrize("wavelengths, reason", [*BAD[:2], ([7.5e-7, 7.5e-7], "distinct"),
                                                 ([7.5e-7, 1.064e-6], "250-1000 nm")])  # no extinction data
def test_cli_unmix_refuses_before_reconstructing(tmp_path, capsys, wavelengths, reason):
    files = []
    for k in range(len(wavelengths)):
        p = tmp_path / f"w{k}.npy"
        np.save(p, np.zeros((64, 4, 4), np.float32))
        files.append(str(p))
    out = tmp_path / "out"
    rc = fpscan_main(["unmix", *files, "--wavelengths", *map(repr, wavelengths), "--dt", "2e-8", "--dx", "1e-4",
                      "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and reason in err, err
    assert not out.exists()


@pytest.mark.parametrize("wavelengths, reason", BAD)
def test_api_plans(shared_api, wavelengths, reason):
    acq = {"n_t": 64, "dt": 2e-8, "wavelengths": wavelengths}
    for path in ("/api/plans", "/api/plans/preview"):
        r = shared_api.post(path, json={"kind": "full", "lattice": LATTICE, "acquisition": acq})
        assert r.status_code == 422, r.text
        assert reason in r.text, r.text


@pytest.mark.parametrize("wavelengths, reason", [(BAD[0][0], BAD[0][1]), (BAD[1][0], BAD[1][1]),
                                                 ([7.5e-7, 7.5e-7], "distinct"), ([7.5e-7], "at least two")])
def test_api_unmix(shared_api, wavelengths, reason):
    ids = [f"d{k}" for k in range(len(wavelengths))]  # the wavelengths are checked first
    r = shared_api.post("/api/reconstructions", json={"dataset_ids": ids, "wavelengths": wavelengths,
                                                      "method": "ner", "unmix": {}})
    assert r.status_code == 422, r.text
    assert reason in r.text, r.text
    r = shared_api.post("/api/reconstructions", json={"dataset_ids": [], "wavelengths": [], "method": "ner",
                                                      "unmix": {}})
    assert r.status_code == 422 and "dataset_ids" in r.text, r.text


@pytest.mark.parametrize("params, reason", [
    ({"sound_speed": 1500, "sound_speed_range": [1450, 1600]}, "needs sound_speed='auto'"),
    ({"sound_speed_range": [1450, 1600]}, "needs sound_speed='auto'"),
    ({"sound_speed": "auto", "sound_speed_range": [1600, 1450]}, "c_min < c_max"),
    ({"sound_speed": "fast"}, "auto"),
    ({"c": 1500, "c_range": [1450, 1600]}, "needs sound_speed='auto'"),  # the deprecated names: the same rules
])
def test_api_autofocus_options(shared_api, params, reason):
    from fpscan.service.pipeline import method_options

    r = shared_api.post("/api/reconstructions", json={"dataset_id": "d0", "method": "ner", "params": params})
    assert r.status_code == 422, r.text
    assert reason in r.text, r.text
    if "sound_speed_range" in params or "c_range" in params:
        with pytest.raises(ValueError, match="sound_speed_range"):
            method_options("ner", params)
