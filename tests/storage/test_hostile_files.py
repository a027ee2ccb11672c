"""Files whose structure or numbers no reader foresaw: `fpscan.load_dataset` refuses each with a
ValueError and its reason (never another exception type, a NaN image or an allocation sized by
the file), and `fpscan.reconstruct` refuses a dataset whose numbers are out of bounds
(`fpscan.service.recon.dataset.check_dataset`)."""
from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io

import fpscan
from fpscan.service.formats.dataset import write as write_dataset
from fpscan.service.recon.dataset import GridDataset
from tests.service.hostile_cases import scan_file
from tests.storage.mat_files import write_mat73


def _kwave_h5(path: Path, **attrs) -> Path:
    with h5py.File(path, "w") as f:
        f.create_dataset("sensor_data", data=np.random.default_rng(0).standard_normal((64, 8, 8)).astype("f4"))
        f.create_dataset("text", data="x")
        f.create_dataset("nothing", data=h5py.Empty("f4"))
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4, **attrs})
    return path


def _scan(folder: Path, name: str, edit) -> Path:
    out = folder / name
    shutil.copy(scan_file(folder), out)
    with h5py.File(out, "r+") as f:
        edit(f)
    return out


def _replace(name: str, value):
    def edit(f: h5py.File) -> None:
        del f[name]
        f.create_dataset(name, data=value)
    return edit


def _ipasc(folder: Path, name: str, key: str, value) -> Path:
    source = folder / "export_ipasc.h5"
    if not source.exists():
        fpscan.export_file(scan_file(folder), source, "ipasc")
    out = folder / name
    shutil.copy(source, out)
    with h5py.File(out, "r+") as f:
        del f["meta_data"][key]
        f["meta_data"].create_dataset(key, data=value)
    return out


def _ipasc_plan(folder: Path, name: str, **lattice) -> Path:
    source = folder / "export_ipasc.h5"
    if not source.exists():
        fpscan.export_file(scan_file(folder), source, "ipasc")
    with h5py.File(source) as f:
        plan = json.loads(f["meta_data/fpscan_plan_json"][()].decode())
    plan["lattice"].update(lattice)
    return _ipasc(folder, name, "fpscan_plan_json", json.dumps(plan))


SAMPLES = np.random.default_rng(1).standard_normal((64, 16))


def _mat73_text_dt(path: Path) -> Path:
    """A MAT v7.3 file whose ``dt``, of MATLAB class double, holds a string."""
    write_mat73(path, {"sensor_data": SAMPLES.T, "dx": 1e-4})
    with h5py.File(path, "r+") as f:
        f.create_dataset("dt", data="1e-8").attrs["MATLAB_class"] = np.bytes_("double")
    return path

#: (name, make(folder) -> path, load_dataset's keywords, a fragment of the reason)
CASES = [
    ("k-Wave HDF5: the key names a string", lambda d: _kwave_h5(d / "a.h5"), {"key": "text"}, "k-Wave layout"),
    ("k-Wave HDF5: the key names an empty dataspace", lambda d: _kwave_h5(d / "b.h5"), {"key": "nothing"},
     "k-Wave layout"),
    ("k-Wave HDF5: a speed of sound of 1e300 m/s", lambda d: _kwave_h5(d / "c.h5", c_m_per_s=1e300), {},
     "sound_speed must be within"),
    ("k-Wave HDF5: a speed of sound of 1.5 (km/s)", lambda d: _kwave_h5(d / "c2.h5", c_m_per_s=1.5), {},
     "sound_speed must be within"),
    ("k-Wave HDF5: dt of 1e300 s", lambda d: _kwave_h5(d / "dt.h5", dt_s=1e300), {}, "dt 1e+300 s is implausible"),
    ("k-Wave HDF5: a pitch of 1e-300 m", lambda d: _kwave_h5(d / "dx.h5", dx_m=1e-300), {}, "implausible"),
    ("MAT v5: Nt = inf", lambda d: scipy.io.savemat(d / "nt.mat", {"sensor_data": SAMPLES, "dt": 1e-8, "dx": 1e-4,
                                                                   "Nt": np.inf}) or d / "nt.mat", {},
     "k-Wave MAT-file"),
    ("MAT v5: complex sensor data", lambda d: scipy.io.savemat(d / "cx.mat", {"sensor_data": SAMPLES + 5j, "dt": 1e-8,
                                                                          "dx": 1e-4}) or d / "cx.mat", {},
     "complex"),
    ("MAT v7.3: dt stored as text in a double", lambda d: _mat73_text_dt(d / "t.mat"), {}, "k-Wave MAT-file"),
    ("scan file: no dt_s", lambda d: _scan(d, "s1.h5", lambda f: f.attrs.__delitem__("dt_s")), {}, "dt_s"),
    ("scan file: a number as its plan", lambda d: _scan(d, "s2.h5", _replace("plan_json", 5)), {}, "scan file"),
    ("scan file: fewer positions than points", lambda d: _scan(d, "s3.h5", _replace("positions", np.zeros((29, 2)))),
     {}, "/positions has shape (29, 2), not (30, 1 or 2)"),
    ("scan file: dt_s NaN", lambda d: _scan(d, "s4.h5", lambda f: f.attrs.__setitem__("dt_s", np.nan)), {},
     "dt must be finite"),
    ("scan file: indices outside the lattice", lambda d: _scan(d, "s5.h5", _replace("indices", np.full((30, 2), 1000,
                                                                                                    np.int32))),
     {}, "inside its 6 x 5 lattice"),
    ("IPASC: fpscan_spatial_dimensions = inf", lambda d: _ipasc(d, "i1.h5", "fpscan_spatial_dimensions", np.inf), {},
     "IPASC"),
    ("IPASC: fpscan_dt_s an array", lambda d: _ipasc(d, "i2.h5", "fpscan_dt_s", np.array([1.0, 2.0])), {}, "IPASC"),
    ("IPASC: a plan lattice of 1e9 x 5 points", lambda d: _ipasc_plan(d, "i3.h5", n_x=10**9), {},
     "lattice must have 1 to"),
    ("IPASC: lattice indices outside the lattice", lambda d: _ipasc(d, "i4.h5", "fpscan_lattice_indices",
                                                                    np.full((30, 2), 999)), {}, "inside"),
]


@pytest.mark.parametrize("name, make, keywords, reason", CASES, ids=[c[0] for c in CASES])
def test_a_hostile_file_is_refused_with_a_value_error(tmp_path, name, make, keywords, reason):
    path = make(tmp_path)
    with pytest.raises(ValueError) as caught:  # a KeyError, TypeError, OverflowError... fails the test
        fpscan.load_dataset(path, **keywords)
    assert reason.lower() in str(caught.value).lower(), str(caught.value)


def _points_file(folder: Path, **edits) -> Path:
    pts = GridDataset(np.random.default_rng(2).standard_normal((64, 8, 8)).astype("f4"), 1e-4, 1e-8,
                      1500.0).to_points()
    pts.indices = np.stack(np.meshgrid(np.arange(8), np.arange(8)), -1).reshape(-1, 2)
    pts.lattice = {"n_x": 8, "n_y": 8, "pitch": 1e-4}
    path = folder / "points.h5"
    write_dataset(path, pts)
    with h5py.File(path, "r+") as f:
        f.attrs.update(edits)
    return path


@pytest.mark.parametrize("edits, reason", [
    ({"lattice_shape": (10**6, 10**6)}, "lattice must have 1 to"),  # 1e12 points: never allocated
    ({"lateral_shift_m": (np.nan, 0.0)}, "lateral_shift must be finite"),
    ({"lateral_shift_m": (1e-3, 0.0, 0.0)}, "one value per lateral axis"),
])
def test_a_dataset_file_out_of_bounds_is_refused(tmp_path, edits, reason):
    with pytest.raises(ValueError, match=reason):
        fpscan.load_dataset(_points_file(tmp_path, **edits))


def test_reconstruct_refuses_a_dataset_whose_numbers_are_out_of_bounds():
    good = GridDataset(np.random.default_rng(3).standard_normal((64, 8)), dx=1e-4, dt=1e-4 / 1500, sound_speed=1500.0)
    assert np.isfinite(fpscan.reconstruct(good, "ner", quiet=True).p0).all()
    for change, reason in (({"sound_speed": 1e300}, "sound_speed must be within"),
                           ({"sound_speed": 1.5}, "sound_speed must be within"),
                           ({"dt": 1e300}, "implausible"), ({"dx": 1e-300}, "implausible"),
                           ({"lateral_shift": (np.nan,)}, "finite")):
        bad = GridDataset(good.data, **{"dx": good.dx, "dt": good.dt, "sound_speed": good.sound_speed, **change})
        with pytest.raises(ValueError, match=reason):
            fpscan.reconstruct(bad, "ner", quiet=True)
    with pytest.raises(ValueError, match="GridDataset or PointDataset"):
        fpscan.reconstruct(good.data, "ner", quiet=True)


def test_numpy_scalars_get_the_plausibility_check_of_python_numbers(tmp_path):
    path = tmp_path / "g.npy"
    np.save(path, SAMPLES)
    for dt in (20.0, np.float32(20.0), np.int64(20)):
        with pytest.raises(ValueError, match="did you mean 20 ns"):
            fpscan.load_dataset(path, dt=dt, dx=1e-4)


def test_samples_beyond_the_working_precision_are_named_not_returned_as_nan():
    huge = GridDataset(np.random.default_rng(4).standard_normal((64, 8)) * 1e300, dx=1e-4, dt=1e-4 / 1500,
                       sound_speed=1500.0)
    with warnings.catch_warnings(), pytest.raises(ValueError, match="samples reach 3.*e\\+300, and float32 holds"):
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy's overflow on the way: what the error names
        fpscan.reconstruct(huge, "ner", quiet=True)
    assert np.isfinite(fpscan.reconstruct(huge, "ner", quiet=True, dtype="float64").p0).all()
