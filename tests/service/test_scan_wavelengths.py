"""A two-wavelength scan job over HTTP (real uvicorn, real pty simulator with an HbO2/Hb
phantom): the live preview shows the chosen wavelength, exactly what the preview
renderer makes of that wavelength's A-lines; a wavelength the plan lacks is a 422; an
unmixing job on the scan job recovers each ball's sO2 at its centre."""
from __future__ import annotations

import numpy as np
import pytest

from tests.service.service_servers import Server, needs_recon, wait_job

pytestmark = [needs_recon, pytest.mark.timeout(180)]
WAVELENGTHS = [7.6e-7, 8.5e-7]


def test_preview_shows_the_chosen_wavelength(tmp_path):
    from fpscan.driver.scanfile import read_scan
    from fpscan.driver.simulator import SimulatedScanner
    from fpscan.driver.sources import BallSource
    from fpscan.physics import Ball
    from fpscan.service.jobs.preview import render_preview, render_preview_png
    from fpscan.service.spectral import read_unmix

    # sO2 0.3 vs 1.0: at 760 nm the first ball is the brighter, at 850 nm the second
    balls = [Ball(3e-4, -2e-4, 1.0e-3, 1.5e-4, 1.0), Ball(-4e-4, 3e-4, 1.4e-3, 1.5e-4, 1.0)]
    sim = SimulatedScanner(source=BallSource(balls, so2=[0.3, 1.0]), prf=0.0, seed=1).start()
    srv = Server(tmp_path / "srv", devices={"sim": sim.path}).start()
    try:
        with srv.client() as c:
            pts = [[ix, iy] for iy in range(10) for ix in range(10)]
            r = c.post("/api/plans", json={
                "lattice": {"n_x": 10, "n_y": 10, "pitch": 1e-4}, "points": pts,
                "acquisition": {"n_t": 96, "dt": 2e-8, "prf": 0.0, "wavelengths": WAVELENGTHS}})
            assert r.status_code == 201, r.text
            plan_id = r.json()["id"]
            bad = c.post("/api/scans", json={"plan_id": plan_id, "scanner_id": "sim",
                                             "preview_wavelength": 2})
            assert bad.status_code == 422 and "preview_wavelength" in bad.text
            r = c.post("/api/scans", json={"plan_id": plan_id, "scanner_id": "sim",
                                           "preview_wavelength": 1})
            assert r.status_code == 202, r.text
            job_id = r.json()["id"]
            assert wait_job(c, job_id)["state"] == "succeeded"
            info = c.get(f"/api/scans/{job_id}/preview").json()
            assert info["wavelength_index"] == 1 and info["points_used"] == 100
            png = c.get(f"/api/scans/{job_id}/preview/xy.png").content
            f = c.get(f"/api/scans/{job_id}/file")
            path = tmp_path / "scan.h5"
            path.write_bytes(f.content)
            # unmixing straight from the two-wavelength scan job: every wavelength
            # reconstructed, then HbO2/Hb per voxel; at each ball's centre its own sO2
            r = c.post("/api/reconstructions", json={"scan_job_id": job_id, "method": "nedner", "unmix": {}})
            assert r.status_code == 202, r.text
            unmix_job = wait_job(c, r.json()["id"])
            assert unmix_job["state"] == "succeeded", unmix_job
            (tmp_path / "unmix.h5").write_bytes(c.get(f"/api/reconstructions/{unmix_job['id']}/unmix.h5").content)
    finally:
        srv.stop()
        sim.stop()
    scan = read_scan(path)
    assert scan.completed_all.all() and scan.n_wavelengths == 2
    u = read_unmix(tmp_path / "unmix.h5")
    assert u["wavelengths_m"].tolist() == WAVELENGTHS
    for ball, so2 in zip(balls, (0.3, 1.0), strict=True):
        at = tuple(int(np.argmin(np.abs(u[a] - v))) for a, v in (("z", ball.z), ("y", ball.y), ("x", ball.x)))
        assert u["mask"][at] and abs(float(u["so2"][at]) - so2) < 0.05, (so2, u["so2"][at])
    at = {}
    for w in (0, 1):
        r = render_preview(str(path), wavelength_index=w)
        at[w] = render_preview_png(r["mips"]["xy"], "xy", r["axes"], r["points_used"])
    assert png == at[1] and at[0] != at[1]
