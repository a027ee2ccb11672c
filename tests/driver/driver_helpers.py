"""Plans for the driver tests, built directly from the plan JSON contract
(docs/architecture.md) so the tests do not depend on the planner."""
from __future__ import annotations

import hashlib
import json

import numpy as np


def grid_plan(n_x: int, n_y: int, pitch: float = 6e-5, *, n_t: int = 256, dt: float = 8e-9,
              n_points: int | None = None, prf: float = 50.0, averages: int = 1,
              serpentine: bool = True) -> dict:
    """A full-lattice (or first-n_points) serpentine plan as plan JSON (a dict)."""
    idx = []
    for iy in range(n_y):
        xs = range(n_x) if (iy % 2 == 0 or not serpentine) else range(n_x - 1, -1, -1)
        idx.extend([ix, iy] for ix in xs)
    if n_points is not None:
        idx = idx[:n_points]
    pos = [[(ix - (n_x - 1) / 2) * pitch, (iy - (n_y - 1) / 2) * pitch] for ix, iy in idx]
    plan = {
        "format": "fpscan-plan/1",
        "lattice": {"n_x": n_x, "n_y": n_y, "pitch": pitch},
        "mask": {"kind": "grid", "params": {}, "requested_points": len(idx),
                 "obtained_points": len(idx), "weight_ratio": 1.0},
        "points": {"indices": idx, "positions": pos, "weights": [pitch * pitch] * len(idx)},
        "order": "serpentine",
        "acquisition": {"n_t": n_t, "dt": dt, "averages": averages, "wavelengths": [7.5e-7],
                        "prf": prf, "sound_speed": 1500.0},
    }
    canon = json.dumps(plan, sort_keys=True, separators=(",", ":")).encode()
    plan["id"] = hashlib.sha256(canon).hexdigest()
    return plan


def small_phantom():
    """Three balls under a small lattice (m, Pa)."""
    from fpscan.physics import Ball

    return [Ball(0.0, 0.0, 1.0e-3, 0.15e-3, 1.0), Ball(0.3e-3, -0.2e-3, 0.6e-3, 0.1e-3, 0.7),
            Ball(-0.4e-3, 0.3e-3, 1.4e-3, 0.2e-3, 1.2)]


def read_record(path, plan_id: str):
    """The simulator's ground truth for a plan: (samples ``(n_wavelengths, n_points, n_t)``,
    scale, dc_level, sent ``(n_wavelengths, n_points)``)."""
    import h5py

    with h5py.File(path, "r") as f:
        g = f[f"plans/{plan_id}"]
        return (np.asarray(g["samples"]), np.asarray(g["scale"]), np.asarray(g["dc_level"]),
                np.asarray(g["sent"]))
