"""IPASC export of a two-wavelength scan: the wavelength axis, checked by PACFISH."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.driver.scanfile import ScanFile, read_scan
from fpscan.service.formats.ipasc import export_scan, read_ipasc
from tests.storage.storage_helpers import assert_pacfish_checks_pass, build_plan, meta, samples

WAVELENGTHS = (7.6e-7, 8.5e-7)


def two_wavelength_scan(path, plan, complete_second=None):
    """Write every point at wavelength 0 and ``complete_second`` (default all) at 1; the
    A-line of (w, k) is ``samples(1000 w + k)``."""
    n, n_t = len(plan["points"]["indices"]), plan["acquisition"]["n_t"]
    with ScanFile.create(path, plan, instrument={"idn": "fpscan,simFP,42,1.0"},
                         software_version="test") as sf:
        for k in range(n):
            sf.append(k, samples(k, n_t), meta(k) | {"wavelength_index": 0})
        for k in (range(n) if complete_second is None else complete_second):
            sf.append(k, samples(1000 + k, n_t),
                      meta(k) | {"wavelength_index": 1, "pulse_energy_j": 4e-3,
                                 "excitation_wavelength_m": WAVELENGTHS[1]})
    return path


def test_two_wavelengths_pacfish_checks_and_round_trip(tmp_path):
    pf = pytest.importorskip("pacfish")
    plan = build_plan(4, 3, 40, wavelengths=WAVELENGTHS)
    scan = two_wavelength_scan(tmp_path / "scan.h5", plan)
    out = export_scan(scan, tmp_path / "x_ipasc.h5")
    data = pf.load_data(str(out))
    ref = read_scan(scan)
    assert data.binary_time_series_data.shape == (12, 40, 2, 1)
    for w in range(2):  # bit-exact DC-normalised pressure at each wavelength
        np.testing.assert_array_equal(data.binary_time_series_data[:, :, w, 0],
                                      ref.pressure_all[w])
    np.testing.assert_array_equal(data.get_acquisition_wavelengths(), WAVELENGTHS)
    np.testing.assert_allclose(data.meta_data_acquisition["pulse_energy"], [2e-3, 4e-3])
    assert_pacfish_checks_pass(pf, data)
    # our reader gives each wavelength back
    r1 = read_ipasc(out, wavelength_index=1)
    np.testing.assert_array_equal(r1["alines"], ref.pressure_all[1])
    np.testing.assert_array_equal(r1["wavelengths"], WAVELENGTHS)


def test_partial_second_wavelength_exports_points_complete_at_both(tmp_path):
    plan = build_plan(4, 3, 24, wavelengths=WAVELENGTHS)
    done = [0, 3, 4, 11]
    scan = two_wavelength_scan(tmp_path / "scan.h5", plan, complete_second=done)
    r = read_ipasc(export_scan(scan, tmp_path / "x.h5"), wavelength_index=1)
    ref = read_scan(scan)
    np.testing.assert_array_equal(r["alines"], ref.pressure_all[1][done])
    np.testing.assert_array_equal(r["positions"], ref.positions[done])
