"""Honest progress: a reconstruction job's progress events rise through the reconstruct
stage with the reconstruction's own per-chunk fractions (not one jump from 20 % to 90 %),
read from the Server-Sent Events of a real server."""
from __future__ import annotations

import io

import numpy as np

from tests.service.service_servers import Server, needs_recon
from tests.service.test_recon_jobs import sse_events

pytestmark = needs_recon


def test_progress_events_strictly_increase_through_reconstruction(tmp_path):
    n, n_t = 96, 2048  # NEDNER over 9216 points: seconds of chunks even on an idle machine (the server polls 4x per second)
    data = np.random.default_rng(1).standard_normal((n_t, n, n)).astype(np.float32)
    buf = io.BytesIO()
    np.save(buf, data)
    srv = Server(tmp_path / "data").start()
    try:
        with srv.client() as api:
            r = api.post("/api/datasets", data={"format": "npy", "dt": "2e-8", "dx": "1e-4"},
                         files={"file": ("d.npy", buf.getvalue(), "application/octet-stream")})
            assert r.status_code == 201, r.text
            r = api.post("/api/reconstructions", json={"dataset_id": r.json()["dataset_id"], "method": "nedner",
                                                       "params": {"eps": 1e-6, "dtype": "float64"}})
            assert r.status_code == 202, r.text
            events = sse_events(api, r.json()["id"], timeout=300)
    finally:
        srv.stop()
    assert [e["data"]["state"] for e in events if e["event"] == "state"][-1] == "succeeded"
    progress = [e["data"] for e in events if e["event"] == "progress"]
    fractions = [p["fraction"] for p in progress if p.get("stage") == "reconstructing"]
    assert len(fractions) >= 3, progress  # real fractions in between, not one jump
    assert all(b > a for a, b in zip(fractions, fractions[1:])), fractions
    assert fractions[0] >= 0.2 and fractions[-1] <= 0.9
    assert any(0.25 < f < 0.85 for f in fractions), fractions
    everything = [p["fraction"] for p in progress]
    assert all(b >= a for a, b in zip(everything, everything[1:])), everything  # never backwards
