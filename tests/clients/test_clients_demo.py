"""`fpscan demo` run as a user runs it (a subprocess, small settings to stay quick): every
promised file exists and opens (h5py, Pillow), and report.json's figures hold up against
an independent check (the phantom's p0 from fpscan.physics on the volume's own grid)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.clients.clients_servers import clean_env, has_command


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    if not (has_command("serve") and has_command("sim")):
        pytest.skip("`fpscan serve`/`fpscan sim` not available yet")
    out = tmp_path_factory.mktemp("demo") / "demo-output"
    res = subprocess.run([sys.executable, "-m", "fpscan", "demo", "--out", str(out), "--quiet",
                          "--lattice", "64", "--pitch", "125e-6", "--points", "400", "--n-t", "384",
                          "--dt", "16e-9"],
                         capture_output=True, text=True, timeout=300, env=clean_env())
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    return out, report, res


def test_demo_report(demo):
    _out, report, _res = demo
    assert report["skipped"] == [], report["skipped"]
    assert "error" not in report
    plans = report["plans"]
    assert plans["equisteradian"]["n_points"] < plans["full"]["n_points"] == 64 * 64
    for name in ("equisteradian", "full"):
        scan = report["scans"][name]
        assert scan["points"] == plans[name]["n_points"]
        assert scan["acquisition_s"] > 0
        # what was measured is what the user waited for, and says so: the scan job's own
        # acquisition (first to last A-line) lies within the job, the job within the wait
        assert scan["acquisition_s"] <= scan["job_run_s"] <= scan["waited_s"]
        assert scan["points_per_s"] == pytest.approx(scan["points"] / scan["acquisition_s"])
        assert plans[name]["expected_scan_time_s"] is None  # the demo's simulator is unthrottled
    rec = report["reconstructions"]
    assert set(rec) == {"nedner", "ner_dense"}
    assert rec["nedner"]["points_used"] == plans["equisteradian"]["n_points"]
    for r in rec.values():
        assert r["reconstruction_s"] > 0
        assert -1.0 <= r["cc_phantom"] <= 1.0
    # the sparse NEDNER image looks like the phantom and like the dense reference
    # (seen: 0.81 and 0.83 in the xy MIP, 0.95 between the two; noise-free simulator)
    for r in rec.values():
        assert r["cc_phantom_mip_xy"] > 0.7
    assert rec["nedner"]["cc_dense_reference_mip_xy"] > 0.85


def test_demo_files_open(demo):
    import h5py
    from PIL import Image

    from fpscan.driver.sources import default_phantom
    from fpscan.physics import ball_p0

    out, report, _res = demo
    from fpscan.driver.scanfile import read_scan

    for name in ("equisteradian", "full"):
        scan = read_scan(out / f"scan_{name}.h5")
        assert scan.completed.all() and len(scan.completed) == report["plans"][name]["n_points"]
    with h5py.File(out / "scan_equisteradian_ipasc.h5", "r") as f:
        assert f["binary_time_series_data"].shape[0] == report["plans"]["equisteradian"]["n_points"]
    if "live_preview" in report:
        with Image.open(out / report["live_preview"]["file"]) as im:
            assert im.format == "PNG"
    with Image.open(out / "mask_preview.png") as im:
        assert im.format == "PNG"
    for r in report["reconstructions"].values():
        with h5py.File(out / r["volume"], "r") as f:
            p0, z, y, x = (f[k][...] for k in ("p0", "z", "y", "x"))
        assert p0.shape == (len(z), len(y), len(x)) == tuple(r["shape"])
        for plane, fname in r["mips"].items():
            with Image.open(out / fname) as im:
                assert im.format == "PNG" and min(im.size) > 1, plane
        # recompute the reported correlation independently
        truth = ball_p0(default_phantom(), z, x, y)
        cc = np.corrcoef(p0.astype(np.float64).ravel(), truth.ravel())[0, 1]
        assert cc == pytest.approx(r["cc_phantom"], abs=1e-6)
