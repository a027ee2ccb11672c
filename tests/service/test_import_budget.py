"""Every import within its budget, over HTTP from a real server: what an import decodes is
sized before it is decoded, every field nested or not and through every compressed layer,
against the decode budget (``fpscan.service.formats.untrusted.hdf5_limit``), and the import
child's address space is capped at the stated limit itself
(``fpscan.service.formats.untrusted.import_memory_limit``: the memory limit).

Oracles: the files are written here byte by byte as an attacker would (MAT v5 elements with
struct and zlib, ``tests.storage.mat_files``; HDF5 hard links with h5py); the server's and its
children's resident sets are read from ``/proc`` while the upload is answered
(``tests.rss.RssWatch``)."""
from __future__ import annotations

import io
import time

import h5py
import numpy as np
import pytest

from tests.rss import RssWatch
from tests.service.service_servers import Server
from tests.storage.mat_files import (
    mat5_compressed,
    mat5_double,
    mat5_file,
    mat5_struct,
    mat5_zeros_double,
    write_mat73,
)

#: the most an upload that is refused may grow the server's or its import child's resident set
GROWTH_BOUND = 200 * 2**20
#: the server's limits: an import child capped at 1 GiB, decoding at most 512 MiB
MEMORY_LIMIT = 2**30


@pytest.fixture(scope="module")
def budget_server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("budget") / "data",
                 env={"FPSCAN_MEMORY_LIMIT": str(MEMORY_LIMIT), "FPSCAN_UPLOAD_LIMIT": str(256 * 2**20)}).start()
    buf = io.BytesIO()  # one import first: the fork server is running, as on a server that has imported before
    np.save(buf, np.zeros((64, 8), np.float32))
    with srv.client(timeout=300) as api:
        assert api.post("/api/datasets", files={"file": ("warm.npy", buf.getvalue())},
                        data={"format": "npy", "dt": "1e-8", "dx": "1e-4"}).status_code == 201
    yield srv
    srv.stop()


def _upload(srv: Server, path, form: dict) -> tuple[object, int, float]:
    """POST the file; (response, the largest resident-set growth meanwhile, seconds)."""
    # every 3 ms: an import child, forked from the fork server, may live for a few ms only
    with srv.client(timeout=300) as api, open(path, "rb") as fh, \
            RssWatch(session=srv.service.pid, period_s=0.003) as peak:
        t0 = time.perf_counter()
        r = api.post("/api/datasets", files={"file": (path.name, fh)}, data=form)
        took = time.perf_counter() - t0
    return r, peak.growth, took


def double_compressed_kgrid(path, field_bytes: int):
    """The issue's file: a valid k-Wave MAT-file whose ``kgrid.dt`` declares ``field_bytes``
    of zeros, the ``kgrid`` variable compressed twice (a compressed element holding a
    compressed element): the outer layer inflates ~100:1 to the inner zlib stream, which
    inflates ~1000:1."""
    sensor = mat5_compressed(mat5_double("sensor_data", np.random.default_rng(0).standard_normal((16, 128))))
    n = field_bytes // 8
    kgrid = mat5_struct("kgrid", {"dx": mat5_double("", 1e-4), "dt": mat5_zeros_double("", n)}, more=8 * n)
    return mat5_file(path, sensor, mat5_compressed(mat5_compressed(kgrid, zeros=8 * n)))


@pytest.mark.serial
def test_a_twice_compressed_struct_field_is_refused_before_it_is_decoded(budget_server, tmp_path):
    """A 10 kB MAT-file whose kgrid.dt declares 512 MiB through two zlib layers: today's
    main inflated the inner layer in scipy (the 100:1 check saw the outer one only, the size
    check skipped structs) and the import child grew by the whole field; now the field's
    bytes are counted, through both layers, before they are inflated: 422 with the reason."""
    path = double_compressed_kgrid(tmp_path / "kgrid.mat", 512 * 2**20)
    assert path.stat().st_size < 20_000
    r, growth, took = _upload(budget_server, path, {"format": "kwave-mat", "dt": "1e-8", "dx": "1e-4"})
    print(f"twice-compressed kgrid.dt ({path.stat().st_size} B declaring 512 MiB): {r.status_code} in {took:.2f} s, "
          f"largest resident-set growth {growth / 2**20:.1f} MiB: {r.text}")
    assert r.status_code == 422, r.text
    assert "inflates beyond" in r.json()["detail"], r.text
    assert growth < GROWTH_BOUND, f"grew by {growth / 2**20:.0f} MiB"


@pytest.mark.serial
def test_a_struct_of_one_group_linked_many_times_is_refused_before_it_is_read(budget_server, tmp_path):
    """A MAT v7.3 (HDF5) file whose kgrid struct holds 20 fields that are hard links to one
    group, which holds a 32 MiB array: 32 MiB stored, checked once by HDF5's own walk of the
    links (it visits a group once), 640 MiB read by a reader of the struct's fields. Today's
    main read them all; now what the fields declare, nested and each link counted, is summed
    before any is read: 422 with the reason."""
    rng = np.random.default_rng(1)
    path = write_mat73(tmp_path / "linked.mat", {"sensor_data": rng.standard_normal((64, 32)), "dt": 1e-8, "dx": 1e-4,
                                                   "kgrid": {"dt": 1e-8}})
    with h5py.File(path, "r+") as f:
        shared = f.create_group("#refs#/g")
        shared.attrs["MATLAB_class"] = np.bytes_("struct")
        big = shared.create_dataset("k", data=rng.standard_normal((2**22, 1)))  # 32 MiB of noise
        big.attrs["MATLAB_class"] = np.bytes_("double")
        for i in range(20):
            f["kgrid"][f"k{i}"] = shared  # a hard link to the one group
    r, growth, took = _upload(budget_server, path, {"format": "kwave-mat"})
    print(f"struct of 20 links to a 32 MiB group: {r.status_code} in {took:.2f} s, growth {growth / 2**20:.1f} MiB")
    assert r.status_code == 422, r.text
    assert "declare" in r.json()["detail"] and "each link counted" in r.json()["detail"], r.text
    assert growth < GROWTH_BOUND, f"grew by {growth / 2**20:.0f} MiB"


@pytest.mark.serial
@pytest.mark.slow
def test_the_import_child_is_capped_at_the_memory_limit_itself(budget_server, tmp_path):
    """An int8 array of 192 MiB becomes 768 MiB of float32 in the import: over the stated
    cap of 1 GiB (the memory limit) with the child's own 0.2 GB, within today's main's cap
    (memory limit + 2 GiB, which stored it). Refused with 422 naming the limit."""
    path = tmp_path / "int8.npy"
    np.save(path, np.ones((3 * 2**10, 2**8, 2**8), np.int8))
    with budget_server.client(timeout=300) as api, open(path, "rb") as fh:
        r = api.post("/api/datasets", files={"file": ("int8.npy", fh)},
                     data={"format": "npy", "dt": "1e-8", "dx": "1e-4"})
    assert r.status_code == 422, r.text
    assert f"the import's limit of {MEMORY_LIMIT} bytes" in r.json()["detail"], r.text


def test_an_honest_upload_still_fits_the_budget(budget_server):
    """A k-Wave MAT-file with a struct, compressed once as MATLAB writes it, is stored."""
    buf = io.BytesIO()
    import scipy.io

    scipy.io.savemat(buf, {"sensor_data": np.random.default_rng(2).standard_normal((32, 256)),
                           "kgrid": {"dt": 1e-8, "dy": 1e-4, "Nt": 256.0}}, do_compression=True)
    with budget_server.client(timeout=300) as api:
        r = api.post("/api/datasets", files={"file": ("ok.mat", buf.getvalue())}, data={"format": "kwave-mat"})
    assert r.status_code == 201, r.text
    assert r.json()["shape"] == [256, 32]
