"""Helpers for the storage tests: plans and A-lines for real scan files."""
from __future__ import annotations

import numpy as np

from fpscan.driver.plan import plan_id_of

PITCH = 1e-4


def build_plan(n_x: int = 6, n_y: int = 5, n_t: int = 48, wavelengths=(7.5e-7,),
               drop: int = 0) -> dict:
    """A full-lattice plan (serpentine-free, row by row), last ``drop`` points removed;
    ``n_y == 1`` gives a 2-D (line) plan with positions ``(n, 1)``."""
    idx = [[i, j] for j in range(n_y) for i in range(n_x)]
    idx = idx[:len(idx) - drop]
    x = lambda i: (i - (n_x - 1) / 2) * PITCH
    y = lambda j: (j - (n_y - 1) / 2) * PITCH
    pos = [[x(i)] if n_y == 1 else [x(i), y(j)] for i, j in idx]
    plan = {
        "format": "fpscan-plan/1",
        "lattice": {"n_x": n_x, "n_y": n_y, "pitch": PITCH},
        "mask": {"kind": "full", "params": {}},
        "points": {"indices": idx, "positions": pos,
                   "weights": [PITCH ** (2 if n_y > 1 else 1) * (1 + 0.1 * k)
                               for k in range(len(idx))]},
        "order": "rows",
        "acquisition": {"n_t": n_t, "dt": 2e-8, "averages": 1, "wavelengths": list(wavelengths),
                        "prf": 0.0, "sound_speed": 1490.0},
    }
    plan["id"] = plan_id_of(plan)
    return plan


def samples(k: int, n_t: int) -> np.ndarray:
    return np.random.default_rng(k).integers(-3000, 3000, n_t).astype(np.int16)


def meta(k: int) -> dict:
    return dict(run_id=1, boot_id=9, point_index=k, pulse_number=k, timestamp_s=0.01 * k,
                bias_wavelength_m=1.55e-6, dc_level=0.8 + 0.01 * k, pulse_energy_j=2e-3,
                dt_s=2e-8, scale=1e-3, offset=1e-4 * (k % 3))


def assert_pacfish_checks_pass(pf, data) -> None:
    """IPASC's own verdict on ``data`` (a ``pacfish.PAData``), each part asserted on its
    own so that a failure names the part: completeness and consistency of the acquisition
    and device metadata, consistency of the binary data. ``pf``: the pacfish module."""
    acq, dev = data.meta_data_acquisition, data.meta_data_device
    completeness, consistency = pf.CompletenessChecker(), pf.ConsistencyChecker()
    assert completeness.check_acquisition_meta_data(acq)
    assert consistency.check_acquisition_meta_data(acq)
    assert completeness.check_device_meta_data(dev)
    assert consistency.check_device_meta_data(dev)
    assert consistency.check_binary_data(data.binary_time_series_data)
