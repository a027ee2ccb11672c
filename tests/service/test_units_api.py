"""The unit rules of fpscan.driver.units through the HTTP API: the same implausible values as the
CLI tests (tests/plans/test_units.py) are a 422 whose reason names the likely unit; text
with a unit is accepted and gives the plan the SI numbers give."""
from __future__ import annotations

import io

import numpy as np
import pytest

from tests.waits import HANG_S

LATTICE = {"n_x": 40, "n_y": 40, "pitch": 6e-5}
EQ = {"kind": "equisteradian", "params": {"depth": 2e-3, "n_points": 60}}


@pytest.mark.parametrize("change, names", [
    ({"lattice": {**LATTICE, "pitch": 60}}, ["pitch 60 m", "60 µm"]),
    ({"params": {"depth": 3.6, "n_points": 60}}, ["depth 3.6 m", "3.6 mm"]),
    ({"acquisition": {"dt": 8}}, ["dt 8 s", "8 ns"]),
    ({"acquisition": {"n_t": 4096, "dt": 8e-9, "prf": 1e5}}, ["PRF 100 kHz", "n_t·dt"]),
    ({"acquisition": {"sound_speed": 1.5}}, ["1.5 m/s", "km/s"]),
])
def test_api_unit_mistakes_are_422_naming_the_unit(shared_api, change, names):
    body = {"lattice": LATTICE, **EQ, **change}
    for path in ("/api/plans", "/api/plans/preview"):  # the web form previews through the API
        r = shared_api.post(path, json=body)
        assert r.status_code == 422, r.text
        assert all(n in r.json()["detail"] for n in names), r.json()


def test_api_units_in_text_and_force(shared_api):
    si = shared_api.post("/api/plans", json={"lattice": LATTICE, **EQ,
                                             "acquisition": {"dt": 8e-9, "prf": 500}})
    text = shared_api.post("/api/plans", json={"lattice": {**LATTICE, "pitch": "60um"}, **EQ,
                                               "acquisition": {"dt": "8 ns", "prf": "500Hz"}})
    assert si.status_code == text.status_code == 201, text.text
    assert si.json()["id"] == text.json()["id"]
    r = shared_api.post("/api/plans", json={"lattice": LATTICE, **EQ, "force": True,
                                            "acquisition": {"sound_speed": 2500}})
    assert r.status_code == 201, r.text


def test_upload_dt_dx_mistakes_are_422(shared_api):
    buf = io.BytesIO()
    np.save(buf, np.zeros((16, 4, 4), dtype=np.float32))
    for form, name in (({"dt": "20", "dx": "1e-4"}, "20 ns"), ({"dt": "2e-8", "dx": "100"}, "100 µm")):
        r = shared_api.post("/api/datasets", data={"format": "npy", **form},
                            files={"file": ("d.npy", buf.getvalue(), "application/octet-stream")})
        assert r.status_code == 422 and name in r.json()["detail"], r.text


def test_recon_sound_speed_rule_422_and_force(shared_server, shared_api, tmp_path):
    """The speed-of-sound rule of the CLI and the library over HTTP: a reconstruction's c
    (or an upload's c) outside 1000-2000 m/s is a 422 naming the likely unit; with
    ``force`` it is accepted (the upload form and ReconParams), and so is
    ``fpscan recon --server --c 2500 --force``."""
    import subprocess
    import sys

    x = tmp_path / "x.npy"
    np.save(x, np.zeros((16, 4, 4), dtype=np.float32))
    upload = {"format": "npy", "dt": "2e-8", "dx": "1e-4"}
    files = {"file": ("d.npy", x.read_bytes(), "application/octet-stream")}
    r = shared_api.post("/api/datasets", data={**upload, "c": "2500"}, files=files)
    assert r.status_code == 422 and "sound speed 2500 m/s" in r.json()["detail"], r.text
    r = shared_api.post("/api/datasets", data={**upload, "c": "2500", "force": "true"}, files=files)
    assert r.status_code == 201, r.text
    dataset_id = r.json()["dataset_id"]
    for params, name in (({"sound_speed": 2500}, "sound_speed: sound speed 2500 m/s"), ({"c": 1.5}, "1.5 km/s"),
                         ({"sound_speed": "auto", "sound_speed_range": [900, 1600]},
                          "sound_speed_range: sound speed 900 m/s")):
        r = shared_api.post("/api/reconstructions", json={"dataset_id": dataset_id, "method": "ner",
                                                          "params": params})
        assert r.status_code == 422 and name in r.json()["detail"], r.text
    r = shared_api.post("/api/reconstructions", json={"dataset_id": dataset_id, "method": "ner",
                                                      "params": {"c": 2500, "force": True}})
    assert r.status_code == 202, r.text

    cli = subprocess.run([sys.executable, "-m", "fpscan", "recon", str(x), "--server", shared_server.url,
                          "--token", shared_server.token, "--dt", "20ns", "--dx", "100um", "--c", "2500",
                          "--force", "--method", "ner", "-q", "--out", str(tmp_path / "r")],
                         capture_output=True, text=True, timeout=HANG_S)
    assert cli.returncode == 0, cli.stderr
    assert (tmp_path / "r" / "volume.h5").is_file()


def test_api_plan_lengths_take_units_and_a_depth_below_a_pitch_is_refused(shared_api):
    """docs/api.md says plan lengths take units: "3.6mm" for the depth (and a
    point of interest with units, negative included) gives the plan the SI numbers give;
    depth 1e-300 m (200 points asked gave a 1-point plan) is a 422 naming why."""
    si = shared_api.post("/api/plans", json={"lattice": LATTICE, "kind": "equisteradian",
                                             "params": {"depth": 3.6e-3, "n_points": 60, "poi": [-2e-4, 2e-4]}})
    text = shared_api.post("/api/plans", json={"lattice": LATTICE, "kind": "equisteradian",
                                               "params": {"depth": "3.6mm", "n_points": 60, "poi": ["-0.2mm", "200um"]}})
    assert si.status_code == text.status_code == 201, text.text
    assert si.json()["id"] == text.json()["id"]
    for depth in (1e-300, "1e-300 m", "30um"):
        r = shared_api.post("/api/plans", json={"lattice": LATTICE, "kind": "equisteradian",
                                                "params": {"depth": depth, "n_points": 200}})
        assert r.status_code == 422 and "below one lattice pitch" in r.json()["detail"], r.text
    short = shared_api.post("/api/plans", json={"lattice": LATTICE, "kind": "equisteradian",
                                                "params": {"depth": "60um", "n_points": 1000}})
    assert short.status_code == 201 and short.json()["n_points"] < 900, short.text
    assert short.json()["shortfall"].startswith(f"{short.json()['n_points']} of 1000 points asked: "), short.json()
    got = text.json()["n_points"]  # the ring design's last ring is taken whole: a note says so when that is many more
    if got * 0.9 > 60:
        assert text.json()["shortfall"].startswith(f"{got} points for the 60 asked: "), text.json()
    else:
        assert text.json()["shortfall"] is None
    r = shared_api.post("/api/plans", json={"lattice": LATTICE, "kind": "equisteradian",
                                            "params": {"depth": "3 furlongs", "n_points": 60}})
    assert r.status_code == 422 and "depth" in r.json()["detail"], r.text


def test_every_plan_quantity_takes_text_with_a_unit_as_the_web_form_sends_it(shared_api):
    """The web page's plan form sends each quantity as typed ("0.15 mm", a bare number with
    its field's unit written after it): every one of them -- pitch, depth, point of interest,
    dt, PRF, sound speed, each wavelength, a point list's coordinates, a spacing -- gives the
    plan the SI numbers give (the same id: the same floats to the last bit), and a depth
    typed "3600 mm" is named the unit mistake a bare 3.6 (m) is."""
    acq_si = {"n_t": 256, "dt": 2e-8, "prf": 25.0, "sound_speed": 1500.0, "wavelengths": [7.5e-7, 8.5e-7]}
    acq_text = {"n_t": 256, "dt": "20 ns", "prf": "25 Hz", "sound_speed": "1.5 km/s",
                "wavelengths": ["750 nm", "0.85 µm"]}
    lattice_text = {**LATTICE, "pitch": "60 µm"}
    for kind, si, text in (
        ("equisteradian", {"depth": 3.6e-3, "n_points": 60, "poi": [-2e-4, 1e-4]},
         {"depth": "3600 µm", "n_points": 60, "poi": ["-0.2 mm", "100 µm"]}),
        ("points", {"points": [[3e-4, -1.2e-4], [0.0, 6e-5]]},
         {"points": [["0.3 mm", "-120 µm"], ["0 mm", "0.06mm"]]}),
        ("hexagonal", {"spacing": 2.4e-4}, {"spacing": "240 µm"}),
    ):
        a = shared_api.post("/api/plans", json={"kind": kind, "lattice": LATTICE, "params": si, "acquisition": acq_si})
        b = shared_api.post("/api/plans", json={"kind": kind, "lattice": lattice_text, "params": text,
                                                "acquisition": acq_text})
        assert a.status_code == b.status_code == 201, (kind, b.text)
        assert a.json()["id"] == b.json()["id"], kind
    for depth in (3.6, "3600 mm"):
        r = shared_api.post("/api/plans/preview", json={"lattice": LATTICE, **EQ, "params": {"depth": depth, "n_points": 60}})
        assert r.status_code == 422 and all(n in r.json()["detail"] for n in ("depth 3.6 m", "3.6 mm")), r.text
    for bad, words in ((["750 kg"], "'750 kg' is not a length"), ({"points": [["1 mm", "2 s"]]}, "'2 s' is not a length")):
        body = ({"lattice": LATTICE, "kind": "full", "acquisition": {"wavelengths": bad}} if isinstance(bad, list)
                else {"lattice": LATTICE, "kind": "points", "params": bad})
        r = shared_api.post("/api/plans/preview", json=body)
        assert r.status_code == 422 and words in r.json()["detail"], r.text
