"""k-Wave MAT-files as an input format (``fpscan.service.formats.kwave_mat``).

Oracles: real k-Wave output (``shared/data/kwave_mat``: a ``kspaceFirstOrder2D`` run saved
by Octave as MAT v5, compressed and not, with its p0), the same arrays written as MATLAB
v7.3 lays them out (``tests.storage.mat_files``), k-Wave's own ``kspaceLineRecon``
(transcribed in ``fpscan.service.recon``, checked against Octave's output in tests/recon), and
arrays built here in k-Wave's layouts."""
from __future__ import annotations

import shutil
import zlib

import h5py
import numpy as np
import pytest
import scipy.io

from fpscan.service import formats
from fpscan.service.pipeline import reconstruct
from fpscan.service.recon import kspace_line_recon
from fpscan.service.storage.loader import detect_format, load_dataset
from tests.storage.mat_files import (
    MAT73_HEADER,
    mat5_compressed,
    mat5_double,
    mat5_element,
    mat5_file,
    mat5_matrix,
    mat5_struct,
    write_mat5,
    write_mat73,
)


@pytest.fixture(scope="module")
def kwave_mat(shared_data, tmp_path_factory):
    """The three k-Wave files: Octave's ``-v6`` and ``-v7`` and a v7.3 made from the same arrays."""
    folder = shared_data / "kwave_mat"
    v6, v7 = folder / "kwave2d_line_sensor_v6.mat", folder / "kwave2d_line_sensor_v7.mat"
    arrays = {k: v for k, v in scipy.io.loadmat(v6).items() if not k.startswith("__")}
    v73 = write_mat73(tmp_path_factory.mktemp("mat") / "kwave2d_line_sensor_v73.mat", arrays)
    p0 = scipy.io.loadmat(folder / "kwave2d_line_sensor_p0.mat")["p0_true"]
    return {"v6": v6, "v7": v7, "v73": v73, "arrays": arrays, "p0": p0}


def test_the_three_mat_versions_read_into_one_dataset_and_image(kwave_mat):
    """MAT v5 (compressed and not) and v7.3 are detected from their content and give the same
    data (k-Wave's (sensor, time) transposed to time first), spacings and image."""
    loaded = {v: load_dataset(kwave_mat[v]) for v in ("v6", "v7", "v73")}
    want = kwave_mat["arrays"]["sensor_data"].T
    for version, ds in loaded.items():
        assert detect_format(kwave_mat[version]) == "kwave-mat"
        assert ds.source == "kwave-mat" and ds.data.shape == (534, 128) == want.shape
        np.testing.assert_array_equal(ds.data, want)
        assert (ds.dt, ds.dx, ds.sound_speed, ds.dy) == (1e-8, 5e-5, 1500.0, None)
    assert [loaded[v].meta["mat_version"] for v in ("v6", "v7", "v73")] == ["5", "5", "7.3"]
    images = [reconstruct(loaded[v], "ner", dtype="float64", n_z=96).p0 for v in ("v6", "v7", "v73")]
    np.testing.assert_array_equal(images[0], images[1])
    np.testing.assert_array_equal(images[0], images[2])


def test_ner_of_the_v5_file_matches_kwaves_p0_as_kwaves_own_recon_does(kwave_mat):
    """NER of the v5 file against the true p0 (a line sensor on the top row: limited view, so
    CC rather than equality), on the simulation's grid (dz = dx), as close as k-Wave's own
    kspaceLineRecon of the same data resampled onto that grid."""
    ds = load_dataset(kwave_mat["v7"])
    p0 = kwave_mat["p0"]  # (96, 128): depth x lateral, k-Wave's x first
    ner = reconstruct(ds, "ner", dtype="float64", dz=ds.dx, n_z=p0.shape[0]).p0
    kw = kspace_line_recon(ds.data, ds.dx, ds.dt, ds.sound_speed)  # rows every c dt
    z_kw, z = np.arange(kw.shape[0]) * ds.sound_speed * ds.dt, np.arange(p0.shape[0]) * ds.dx
    kw = np.stack([np.interp(z, z_kw, kw[:, j]) for j in range(kw.shape[1])], axis=1)
    cc = lambda a: np.corrcoef(a.ravel(), p0.ravel())[0, 1]
    assert cc(ner) > 0.8 and cc(ner) >= cc(kw) - 0.02, (cc(ner), cc(kw))


def test_the_content_decides_not_the_suffix(kwave_mat, tmp_path):
    shutil.copy(kwave_mat["v7"], tmp_path / "sensor_data.h5")
    shutil.copy(kwave_mat["v73"], tmp_path / "sensor_data")
    assert detect_format(tmp_path / "sensor_data.h5") == detect_format(tmp_path / "sensor_data") == "kwave-mat"
    np.save(tmp_path / "array.npy", np.zeros((8, 4)))
    shutil.move(tmp_path / "array.npy", tmp_path / "array.mat")
    assert detect_format(tmp_path / "array.mat") == "npy"


def test_kwave_layouts_and_kgrid_spacings(tmp_path):
    """k-Wave's (n_sensors, n_t) of a full plane in mask order (with the saved sensor mask),
    the (n_t, n_y, n_x) of its examples' reshape, and a time-first 2-D array told apart by
    Nt, each read into time-first data; kgrid's spacings in k-Wave's naming (depth x: our
    x is k-Wave's z, our y its y)."""
    rng = np.random.default_rng(4)
    n_t, n_y, n_z = 20, 4, 5  # k-Wave grid (Nx, Ny, Nz) = (3, 4, 5), sensors on the plane x = 1
    p_tyz = rng.standard_normal((n_t, n_y, n_z))
    kgrid = {"dt": 2e-8, "dx": 1e-4, "dy": 6e-5, "dz": 7e-5, "Nt": float(n_t)}
    mask = np.zeros((3, n_y, n_z), bool)
    mask[0] = True
    # MATLAB's sensor_data rows follow the mask's linear index: y fastest, then z
    in_mask_order = np.stack([p_tyz[:, iy, iz] for iz in range(n_z) for iy in range(n_y)])
    files = {
        "plane, mask order (v5)": write_mat5(tmp_path / "a.mat", {"sensor_data": in_mask_order, "kgrid": kgrid,
                                                                   "sensor": {"mask": mask.astype(np.uint8)}}),
        "p_tyz (v7.3)": write_mat73(tmp_path / "b.mat", {"sensor_data": p_tyz, "kgrid": kgrid,
                                                         "medium": {"sound_speed": 1480.0}}),
    }
    for what, path in files.items():
        ds = load_dataset(path)
        np.testing.assert_array_equal(ds.data, p_tyz, err_msg=what)
        assert (ds.dt, ds.dx, ds.dy) == (2e-8, 7e-5, 6e-5), what
    assert load_dataset(files["p_tyz (v7.3)"]).sound_speed == 1480.0
    line = rng.standard_normal((n_t, 6))  # kspaceLineRecon's p_ty, saved time first
    ds = load_dataset(write_mat73(tmp_path / "c.mat", {"p_ty": line, "Nt": float(n_t), "dy": 5e-5, "dt": 1e-8}))
    np.testing.assert_array_equal(ds.data, line)
    assert ds.dx == 5e-5 and ds.meta["key"] == "p_ty"
    with pytest.raises(ValueError, match="Nt is 21"):
        load_dataset(write_mat5(tmp_path / "d.mat", {"sensor_data": line.T, "Nt": 21.0, "dx": 1e-4, "dt": 1e-8}))
    sparse = mask.copy()
    sparse[0, 0, 0] = False
    with pytest.raises(ValueError, match="not one full plane"):
        load_dataset(write_mat5(tmp_path / "e.mat", {"sensor_data": in_mask_order[1:], "kgrid": kgrid,
                                                     "sensor": {"mask": sparse.astype(np.uint8)}}))


def test_spacings_missing_from_the_file_are_options(tmp_path):
    path = write_mat5(tmp_path / "bare.mat", {"sensor_data": np.ones((8, 30))})
    with pytest.raises(ValueError, match="dt is neither given nor in the MAT-file"):
        load_dataset(path)
    with pytest.raises(ValueError, match="give dx"):
        load_dataset(path, dt=1e-8)
    ds = load_dataset(path, dt=1e-8, dx=1e-4, sound_speed=1490.0)
    assert ds.data.shape == (30, 8) and (ds.dt, ds.dx, ds.sound_speed) == (1e-8, 1e-4, 1490.0)
    with pytest.raises(ValueError, match=r"variables: sensor_data"):
        load_dataset(path, key="p", dt=1e-8, dx=1e-4)


def _zlib_bomb(path, n_bytes: int) -> None:
    """A MAT v5 file of one compressed variable, zeros inflating ~1000:1."""
    import io

    raw = io.BytesIO()
    scipy.io.savemat(raw, {"sensor_data": np.zeros((1, n_bytes // 8))}, do_compression=False)
    body = raw.getvalue()
    packed = zlib.compress(body[128:], 9)
    path.write_bytes(body[:128] + (15).to_bytes(4, "little") + len(packed).to_bytes(4, "little") + packed)


def test_hostile_mat_files_are_refused_with_a_reason(kwave_mat, tmp_path):
    """A zlib bomb is refused before it is inflated past the ratio every HDF5 input obeys; a
    truncated file, a v7.3 file pointing outside itself or declaring what it does not store
    are refused by the same checks as every HDF5 input; a v7.3 file asked to be plain HDF5
    names the format that reads it."""
    _zlib_bomb(tmp_path / "bomb.mat", 40 << 20)
    assert (tmp_path / "bomb.mat").stat().st_size < 100_000
    with pytest.raises(ValueError, match="inflates beyond"):
        load_dataset(tmp_path / "bomb.mat", dt=1e-8, dx=1e-4)
    whole = kwave_mat["v7"].read_bytes()
    (tmp_path / "cut.mat").write_bytes(whole[:len(whole) // 2])
    with pytest.raises(ValueError, match="truncated|corrupt"):
        load_dataset(tmp_path / "cut.mat")
    (tmp_path / "other.h5").touch()
    linked = write_mat73(tmp_path / "linked.mat", kwave_mat["arrays"])
    with h5py.File(linked, "a") as f:
        f["elsewhere"] = h5py.ExternalLink("other.h5", "/x")
    with pytest.raises(ValueError, match="external link"):
        load_dataset(linked)
    promise = write_mat73(tmp_path / "promise.mat", {"dt": 1e-8, "dx": 1e-4})
    with h5py.File(promise, "a") as f:
        ds = f.create_dataset("sensor_data", shape=(4096, 4096), dtype="f8")  # declared, never written
        ds.attrs["MATLAB_class"] = np.bytes_("double")
    with pytest.raises(ValueError, match="unwritten|declare"):
        load_dataset(promise)
    with pytest.raises(ValueError, match="format kwave-mat"):
        load_dataset(kwave_mat["v73"], "kwave-hdf5")
    with pytest.raises(ValueError, match="MAT-file: read it with format kwave-mat"):
        load_dataset(kwave_mat["v7"], "kwave-hdf5")
    (tmp_path / "noise.mat").write_bytes(MAT73_HEADER[:128].replace(b"7.3", b"5.0", 1) + b"\x0e\x00\x00\x00" * 9)
    with pytest.raises(ValueError):
        load_dataset(tmp_path / "noise.mat")
    assert formats.describe(kwave_mat["v73"]) == "a k-Wave MAT-file"


def test_every_field_is_sized_before_it_is_decoded(tmp_path):
    """Each field of a MAT v5 variable, nested or not, is sized from what it declares before
    scipy decodes any of it, against the budget ``max_bytes``: a struct field that is a cell
    array declaring 2**26 elements (512 MiB of slots scipy allocates before it reads one: today's
    main skipped structs and allocated them); a compressed element inside a variable (MATLAB
    never writes one); a variable compressed three times (scipy reads one layer) is read, its
    layers inflated here; an honest struct still reads."""
    sensor = mat5_double("sensor_data", np.random.default_rng(3).standard_normal((8, 64)))
    cell = mat5_matrix("", 1, (2**26, 1), b"")  # mxCELL_CLASS, no element stored
    path = mat5_file(tmp_path / "cell.mat", sensor, mat5_compressed(mat5_struct("kgrid", {"dt": mat5_double("", 1e-8),
                                                                                          "c": cell})))
    with pytest.raises(ValueError, match="need more than the import's limit of 67108864 bytes"):
        load_dataset(path, "kwave-mat", dx=1e-4, max_bytes=64 * 2**20)
    inside = mat5_matrix("dt", 6, (1, 1), mat5_compressed(mat5_element(9, np.float64(1e-8).tobytes())))
    with pytest.raises(ValueError, match="compressed element inside a variable"):
        load_dataset(mat5_file(tmp_path / "inside.mat", sensor, inside), "kwave-mat", dx=1e-4)
    thrice = mat5_compressed(mat5_compressed(mat5_compressed(mat5_struct("kgrid", {"dt": mat5_double("", 1e-8)}))))
    ds = load_dataset(mat5_file(tmp_path / "thrice.mat", sensor, thrice), "kwave-mat", dx=1e-4)
    assert ds.dt == 1e-8 and ds.data.shape == (64, 8)


def test_a_variable_declaring_100k_dimensions_is_refused_as_corrupt(tmp_path):
    """A MAT v5 variable's dimensions are read only up to 64 (k-Wave's arrays have at most 4):
    a few kB of compressed file declaring 100 000 dimensions (whose product, a Python int
    multiplied per dimension, took CPU quadratic in their number) is refused as corrupt."""
    dims = mat5_compressed(mat5_matrix("sensor_data", 6, (2,) * 100_000, b""))
    path = mat5_file(tmp_path / "dims.mat", dims)
    assert path.stat().st_size < 10_000
    with pytest.raises(ValueError, match=r"corrupt \(a variable declares 100000 dimensions; at most 64 are read\)"):
        load_dataset(path, "kwave-mat", dt=1e-8, dx=1e-4)
    honest = mat5_file(tmp_path / "honest.mat", mat5_double("sensor_data", np.ones((4, 16))))
    assert load_dataset(honest, "kwave-mat", dt=1e-8, dx=1e-4).data.shape == (16, 4)


@pytest.mark.parametrize("compressed", [False, True])
def test_the_inflated_stream_is_held_once(tmp_path, compressed):
    """The MAT v5 walker holds the file's variables uncompressed once: written into one buffer
    as they are read (compressed or not) and handed to ``scipy.io.loadmat`` as it is, not
    gathered in parts and joined (which held them twice). Oracle: Python's allocations
    (``tracemalloc``) while a file holding a 24 MiB variable beside the small data is read."""
    import tracemalloc

    held = 24 * 2**20
    junk = np.random.default_rng(5).standard_normal(held // 8).reshape(-1, 1024)
    path = write_mat5(tmp_path / "junk.mat", {"sensor_data": np.ones((4, 16)), "junk": junk}, compressed=compressed)
    del junk
    load_dataset(path, "kwave-mat", dt=1e-8, dx=1e-4)  # imports and caches warmed
    tracemalloc.start()
    try:
        ds = load_dataset(path, "kwave-mat", dt=1e-8, dx=1e-4)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert ds.data.shape == (16, 4)
    print(f"MAT v5 ({'compressed' if compressed else 'uncompressed'}) holding {held} B of variables: "
          f"peak {peak} B ({peak / held:.2f}x)")
    assert peak < 1.5 * held, peak / held
