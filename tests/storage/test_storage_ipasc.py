"""IPASC export/import (fpscan.service.formats.ipasc) against the scan file and against PACFISH,
the IPASC reference implementation, reading our export and writing a foreign file."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from fpscan.driver.scanfile import read_scan
from fpscan.service.formats.ipasc import export_scan, read_ipasc
from tests.storage.storage_helpers import assert_pacfish_checks_pass, build_plan


def test_round_trip_equals_scan(tmp_path, make_scan):
    plan = build_plan(6, 5, 48)
    done = [0, 1, 2, 5, 7, 11, 12, 20, 29]  # a partial scan: only these are exported
    scan = make_scan("scan.h5", plan, done)
    out = export_scan(scan, tmp_path / "scan_ipasc.h5")
    ref = read_scan(scan).completed_only()
    r = read_ipasc(out)
    np.testing.assert_array_equal(r["alines"], ref.pressure)  # float64: bit-exact
    np.testing.assert_array_equal(r["positions"], ref.positions)
    np.testing.assert_array_equal(r["weights"], ref.weights)
    assert r["dt"] == plan["acquisition"]["dt"] and r["c"] == 1490.0
    np.testing.assert_array_equal(r["wavelengths"], [7.5e-7])
    np.testing.assert_array_equal(r["indices"], np.array(plan["points"]["indices"])[done])
    assert r["plan"] == plan
    assert len(r["grid"]) == 2 and len(r["grid"][0]) == 6 and len(r["grid"][1]) == 5
    # the raw layout is the one docs/file-formats.md lists (IPASC export)
    with h5py.File(out, "r") as f:
        assert f["binary_time_series_data"].shape == (len(done), 48, 1, 1)
        m = f["meta_data"]
        assert list(m["sizes"][()]) == [len(done), 48, 1, 1]
        assert m["ad_sampling_rate"][()] == pytest.approx(5e7, rel=1e-15)
        assert m["compression"][()] == b"none"
        for key in ("uuid", "encoding", "data_type", "dimensionality", "speed_of_sound",
                    "acquisition_wavelengths", "measurement_spatial_poses"):
            assert isinstance(m[key], h5py.Dataset), key
        g = f["meta_data_device/general"]
        assert g["num_detectors"][()] == len(done) and g["num_illuminators"][()] == 0
        assert g["field_of_view"].shape == (6,)
        d = f["meta_data_device/detectors/0000000003"]
        np.testing.assert_array_equal(d["detector_position"][()],
                                      [*plan["points"]["positions"][5], 0.0])


def test_2d_plan_round_trip(tmp_path, make_scan):
    plan = build_plan(9, 1, 32)
    scan = make_scan("line.h5", plan)
    r = read_ipasc(export_scan(scan, tmp_path / "line_ipasc.h5", dtype=np.float32))
    ref = read_scan(scan)
    assert r["positions"].shape == (9, 1) and len(r["grid"]) == 1
    np.testing.assert_array_equal(r["positions"], ref.positions)
    np.testing.assert_allclose(r["alines"], ref.pressure, rtol=1e-7)  # float32 export


@pytest.mark.parametrize("points", [None, [0, 2, 3, 7, 9, 10]], ids=["full", "sparse"])
def test_pacfish_reads_our_export(tmp_path, make_scan, points):
    """PACFISH (the IPASC reference implementation) reads our export of a full and of a
    sparse (partial) scan, and its own completeness and consistency checks -- every
    acquisition tag, every detector tag, the binary data -- all pass, none skipped."""
    pf = pytest.importorskip("pacfish")
    from pacfish import MetadataAcquisitionTags as A
    from pacfish import MetadataDeviceTags as D

    plan = build_plan(4, 3, 40)
    scan = make_scan("scan.h5", plan, points)
    out = export_scan(scan, tmp_path / "x_ipasc.h5")
    data = pf.load_data(str(out))
    ref = read_scan(scan).completed_only()
    n = 12 if points is None else len(points)
    np.testing.assert_array_equal(data.binary_time_series_data[:, :, 0, 0], ref.pressure)
    assert data.get_sampling_rate() == pytest.approx(1 / 2e-8, rel=1e-15)
    assert data.get_speed_of_sound() == 1490.0
    assert data.get_acquisition_wavelengths() == pytest.approx(7.5e-7)
    assert data.get_number_of_detectors() == n
    assert data.get_dimensionality() == "time"
    assert data.get_compression() == "none"
    pos = np.array([data.get_detector_position(i) for i in data.get_detector_ids()])
    np.testing.assert_array_equal(pos[:, :2], ref.positions)
    np.testing.assert_array_equal(pos[:, 2], 0.0)
    acq, dev = data.meta_data_acquisition, data.meta_data_device
    assert dev["general"]["unique_identifier"] == "fpscan,simFP,42,1.0"
    # IPASC's own verdict, each part on its own so a failure names the part
    assert_pacfish_checks_pass(pf, data)
    assert pf.quality_check_pa_data(data)
    # and, independently of the checkers' loops, every tag IPASC defines is there
    for tag in A.TAGS:
        assert acq.get(tag.tag) is not None, tag.tag
        assert tag.evaluate_value_range(acq[tag.tag]), tag.tag
    assert len(dev["detectors"]) == n
    for det in dev["detectors"].values():
        for tag in D.TAGS_DETECTORS:
            assert det.get(tag.tag) is not None, tag.tag
            assert tag.evaluate_value_range(det[tag.tag]), tag.tag


def test_we_read_a_pacfish_written_file(tmp_path):
    """A foreign IPASC file (written by PACFISH, no fpscan extras): positions from the
    detector elements, the grid spanned by them, no weights."""
    pf = pytest.importorskip("pacfish")
    from pacfish import MetadataAcquisitionTags as A

    rng = np.random.default_rng(5)
    xs, ys = np.meshgrid(np.arange(4) * 2e-4 - 3e-4, np.arange(3) * 2e-4, indexing="xy")
    xs, ys = xs.ravel(), ys.ravel()
    creator = pf.DeviceMetaDataCreator()
    creator.set_general_information(uuid="foreign", fov=np.array([0, 1, 0, 1, 0, 1.0]))
    for x, y in zip(xs, ys):
        e = pf.DetectionElementCreator()
        e.set_detector_position(np.array([x, y, 0.002]))
        creator.add_detection_element(e.get_dictionary())
    data = rng.standard_normal((12, 30, 2, 1))
    pa = pf.PAData(binary_time_series_data=data, meta_data_device=creator.finalize_device_meta_data())
    pa.meta_data_acquisition = {A.AD_SAMPLING_RATE.tag: 4e7, A.SPEED_OF_SOUND.tag: 1540.0,
                                A.ACQUISITION_WAVELENGTHS.tag: np.array([7e-7, 8e-7]),
                                A.SIZES.tag: np.array(data.shape)}
    path = tmp_path / "foreign.h5"
    pf.write_data(str(path), pa)
    r = read_ipasc(path, wavelength_index=1)
    np.testing.assert_array_equal(r["alines"], data[:, :, 1, 0])
    np.testing.assert_array_equal(r["positions"], np.stack([xs, ys], axis=1))
    assert r["weights"] is None and r["c"] == 1540.0 and r["dt"] == pytest.approx(2.5e-8)
    np.testing.assert_allclose(r["grid"][0], np.arange(4) * 2e-4 - 3e-4, atol=1e-15)
    np.testing.assert_allclose(r["grid"][1], np.arange(3) * 2e-4, atol=1e-15)
    np.testing.assert_array_equal(r["wavelengths"], [7e-7, 8e-7])
    with pytest.raises(ValueError, match="wavelength_index"):
        read_ipasc(path, wavelength_index=2)


def test_concurrent_exports_to_one_target(tmp_path, make_scan):
    """Two HTTP requests may export the same scan at once (threads of one server)."""
    from concurrent.futures import ThreadPoolExecutor

    scan = make_scan("scan.h5", build_plan(4, 4, 32))
    out = tmp_path / "exports" / "job.ipasc.h5"  # folder created on demand
    with ThreadPoolExecutor(4) as pool:
        list(pool.map(lambda _: export_scan(scan, out), range(4)))
    np.testing.assert_array_equal(read_ipasc(out)["alines"], read_scan(scan).pressure)
    assert [p.name for p in out.parent.iterdir()] == ["job.ipasc.h5"]


def test_bad_input(tmp_path, make_scan):
    plan = build_plan(3, 3, 16)
    empty = make_scan("empty.h5", plan, [])
    with pytest.raises(ValueError, match="no completed"):
        export_scan(empty, tmp_path / "e.h5")
    assert not (tmp_path / "e.h5").exists()
    # several wavelengths: only wavelength 0 written, so no point is complete at both
    multi = make_scan("multi.h5", build_plan(3, 3, 16, wavelengths=(7e-7, 8e-7)))
    with pytest.raises(ValueError, match="no completed"):
        export_scan(multi, tmp_path / "m.h5")
    with pytest.raises(ValueError, match="dtype"):
        export_scan(make_scan("ok.h5", plan), tmp_path / "o.h5", dtype=np.int16)

    good = export_scan(tmp_path / "ok.h5", tmp_path / "good.h5")

    def broken(name, edit):
        p = tmp_path / name
        p.write_bytes(good.read_bytes())
        with h5py.File(p, "r+") as f:
            edit(f)
        return p

    def tilt(f):
        f["meta_data_device/detectors/0000000004/detector_position"][2] = 1e-3

    def sizes(f):
        f["meta_data/sizes"][0] = 99

    def fs(f):
        del f["meta_data/ad_sampling_rate"]
        f["meta_data/ad_sampling_rate"] = -1.0

    def nan(f):
        f["binary_time_series_data"][0, 0, 0, 0] = np.nan

    def nodet(f):
        del f["meta_data_device/detectors/0000000008"]

    def nopos(f):
        del f["meta_data_device/detectors/0000000002/detector_position"]

    def pos2(f):
        del f["meta_data_device/detectors/0000000002/detector_position"]
        f["meta_data_device/detectors/0000000002/detector_position"] = [1.0, 2.0]

    for name, edit, what in [("tilt.h5", tilt, "plane"), ("sizes.h5", sizes, "sizes"),
                             ("nopos.h5", nopos, "no detector_position"),
                             ("pos2.h5", pos2, "3 numbers"),
                             ("fs.h5", fs, "ad_sampling_rate"), ("nan.h5", nan, "NaN"),
                             ("nodet.h5", nodet, "detectors")]:
        with pytest.raises(ValueError, match=what):
            read_ipasc(broken(name, edit))
    with pytest.raises(ValueError, match="not an IPASC"):
        read_ipasc(tmp_path / "ok.h5")  # a scan file is not IPASC
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(ValueError, match="not an HDF5"):
        read_ipasc(tmp_path / "text.h5")
    with pytest.raises(FileNotFoundError):
        read_ipasc(tmp_path / "nothing.h5")
