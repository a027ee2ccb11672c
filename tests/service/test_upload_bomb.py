"""Every stored byte is earned: a compressed fill-value bomb
(a gzip-filtered, never-written 2**15 x (2**14 - 1) float32 dataset, fill value 0.5, a few
kB declaring 2 GiB) is refused by the one check of untrusted files, over HTTP and in the
library, before anything large is written; an upload whose decoded dataset does not fit
the free disk (counting imports in flight) is refused with 507 before it is written; a real
gzip-compressed k-Wave file still loads."""
from __future__ import annotations

import os
import shutil
import time

import h5py
import numpy as np
import pytest

from fpscan.service.formats.untrusted import MAX_RATIO, DiskAdmission
from tests.service.hostile_cases import gzip_fill_bomb
from tests.service.service_servers import Server

#: the bomb: 2**15 x (2**14 - 1) float32 = 2 GiB - 128 KiB declared
BOMB_SHAPE = (2**15, 2**14 - 1)
#: the hostile suite's bound on answering a hostile upload (tests/service/test_hostile_inputs.py)
ANSWER_BOUND_S = 5.0


def _tree_bytes(folder) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) if folder.exists() else 0


@pytest.fixture(scope="module")
def bomb_server(tmp_path_factory):
    # the default limits (2 GiB uploads, 8 GiB memory): the bomb's 2 GiB is within the
    # declared-size limit (4 GiB), so only the stored-bytes check can refuse it
    srv = Server(tmp_path_factory.mktemp("bomb") / "data",
                 env={"FPSCAN_UPLOAD_LIMIT": str(2 * 2**30), "FPSCAN_MEMORY_LIMIT": str(8 * 2**30)}).start()
    yield srv
    srv.stop()


@pytest.fixture
def full_server(tmp_path):
    # a disk reserve beyond any free space: the disk is "full" for every upload
    srv = Server(tmp_path / "data", env={"FPSCAN_DISK_RESERVE_BYTES": str(2**60)}).start()
    yield srv
    srv.stop()


@pytest.mark.serial
def test_the_issue_bomb_is_refused_over_http_and_nothing_large_is_written(bomb_server, tmp_path):
    bomb = gzip_fill_bomb(BOMB_SHAPE)(tmp_path)
    declared = BOMB_SHAPE[0] * BOMB_SHAPE[1] * 4
    assert os.path.getsize(bomb) < 8192
    datasets = bomb_server.data_dir / "datasets"
    with bomb_server.client(timeout=60) as api, open(bomb, "rb") as fh:
        t0 = time.perf_counter()
        r = api.post("/api/datasets", files={"file": ("bomb.h5", fh)}, data={"format": "kwave-hdf5"})
        took = time.perf_counter() - t0
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert f"declares {declared} bytes" in detail and "never written" in detail, detail
    assert took < ANSWER_BOUND_S, took
    assert _tree_bytes(datasets) == 0, list(datasets.rglob("*"))
    print(f"bomb: {os.path.getsize(bomb)} B file declaring {declared} B refused (422) in {took:.2f} s: {detail}")


@pytest.mark.parametrize("fmt", ["kwave-hdf5", "fpscan", "ipasc", "dataset", None])
def test_the_issue_bomb_is_refused_by_load_dataset_for_every_format(tmp_path, fmt):
    from fpscan.service.storage.loader import load_dataset

    bomb = gzip_fill_bomb(BOMB_SHAPE)(tmp_path)
    with pytest.raises(ValueError, match="never written"):
        load_dataset(bomb, fmt)


def test_a_file_of_unwritten_chunks_beside_real_data_is_refused(tmp_path):
    """One written chunk does not earn the rest: the unwritten ones are named."""
    from fpscan.service.storage.loader import load_dataset

    path = tmp_path / "partly.h5"
    with h5py.File(path, "w") as f:
        d = f.create_dataset("sensor_data", shape=(1024, 1024), dtype="f4", chunks=(128, 128), compression="gzip")
        d[:128, :128] = np.random.default_rng(0).standard_normal((128, 128))
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    with pytest.raises(ValueError, match="63 of its 64 chunks were never written"):
        load_dataset(path, "kwave-hdf5")


def test_over_compressed_written_data_is_refused_by_its_ratio(tmp_path):
    from fpscan.service.storage.loader import load_dataset
    from tests.service.hostile_cases import gzip_zeros

    path = gzip_zeros(tmp_path)
    with pytest.raises(ValueError, match=f"more than {MAX_RATIO}:1"):
        load_dataset(path, "kwave-hdf5")


def test_real_gzip_kwave_files_still_load(shared_data, tmp_path):
    """The k-Wave reference files (gzip 6 + shuffle, 1.1-1.8:1) load as before, and a
    k-Wave-like file that is mostly (90 %) exact zeros, gzip-compressed, loads too."""
    from fpscan.service.storage.loader import load_dataset

    d3 = load_dataset(shared_data / "kwave3d_balls_yarn.h5", "kwave-hdf5")
    with h5py.File(shared_data / "kwave3d_balls_yarn.h5", "r") as f:
        np.testing.assert_array_equal(d3.data, f["sensor_data/clean"][()])
    d2 = load_dataset(shared_data / "kwave2d_points.h5", "kwave-hdf5")
    assert d2.data.shape == (3519, 1024)
    sparse = np.zeros((2000, 64, 64), np.float32)
    sparse[1800:] = np.random.default_rng(1).standard_normal((200, 64, 64))
    path = tmp_path / "sparse.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("sensor_data", data=sparse, compression="gzip", shuffle=True)
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    np.testing.assert_array_equal(load_dataset(path, "kwave-hdf5").data, sparse)


def test_an_upload_that_does_not_fit_the_disk_gets_507_before_it_is_written(full_server, tmp_path):
    """The server keeps more free than the disk has (FPSCAN_DISK_RESERVE_BYTES): refused
    with 507 and the reason before its body is spooled."""
    path = tmp_path / "ok.npy"
    np.save(path, np.random.default_rng(2).standard_normal((64, 16, 16)).astype(np.float32))
    with full_server.client() as api, open(path, "rb") as fh:
        r = api.post("/api/datasets", files={"file": ("ok.npy", fh)},
                     data={"format": "npy", "dt": "1e-8", "dx": "1e-4"})
    assert r.status_code == 507, r.text
    assert "the upload's body holds" in r.json()["detail"], r.text
    assert _tree_bytes(full_server.data_dir / "datasets") == 0
    with full_server.client() as api:
        assert api.get("/api/datasets").json() == []


def test_the_import_asks_before_writing_the_decoded_dataset(tmp_path):
    """The import child asks the parent (``run_bounded(admit=...)``) with the decoded bytes
    before it writes the dataset file; refused, nothing is written and the reason comes back."""
    from fpscan.service.formats.untrusted import NotAdmitted, run_bounded
    from fpscan.service.storage.loader import import_dataset

    src = tmp_path / "int8.npy"  # 16 kB of int8 on the wire, 64 kB of float32 decoded
    np.save(src, np.random.default_rng(3).integers(-100, 100, (64, 16, 16), dtype=np.int8))
    asked: list[int] = []

    def admit(nbytes: int) -> str | None:
        asked.append(nbytes)
        return "no room on this disk"

    dest = tmp_path / "dest"
    dest.mkdir()
    with pytest.raises(NotAdmitted, match="no room on this disk"):
        run_bounded(import_dataset, src, dest, "npy", dt=1e-8, dx=1e-4, dy=None, sound_speed=None, key=None,
                    timeout=60, admit=admit)
    assert asked == [64 * 16 * 16 * 4] and list(dest.iterdir()) == []
    meta = run_bounded(import_dataset, src, dest, "npy", dt=1e-8, dx=1e-4, dy=None, sound_speed=None, key=None,
                       timeout=60, admit=lambda n: None)
    assert meta["shape"] == [64, 16, 16] and (dest / "dataset.h5").is_file()


def test_two_imports_at_once_cannot_fill_the_disk(tmp_path):
    """The admission counts what imports in flight were admitted for: two that each fit
    the free space alone do not both get in; the second does once the first is done."""
    free = shutil.disk_usage(tmp_path).free
    adm = DiskAdmission(tmp_path, reserve_bytes=0)
    half = free // 2 + free // 8  # each fits alone, both do not
    assert adm.reserve("a", half) is None
    refused = adm.reserve("b", half)
    assert refused is not None and "reserved by uploads, imports and exports in progress" in refused, refused
    assert adm.reserved() == half
    adm.release("a")
    assert adm.reserve("b", half) is None


def test_the_reading_child_runs_below_the_servers_priority():
    """Files are vetted and imported in a child at the caller's priority + CHILD_NICE
    (a burst of uploads must not take the CPU from the server's event loop);
    the child reports its own niceness (``os.nice(0)``)."""
    from fpscan.service.formats.untrusted import CHILD_NICE, run_bounded

    mine = os.nice(0)
    assert run_bounded(os.nice, 0, timeout=60) == min(mine + CHILD_NICE, 19)


def test_a_dataset_linked_many_times_counts_once_per_link(tmp_path):
    """The file's datasets may declare ``max_bytes`` together, each link counted: 20 hard
    links to one 8 MiB array in a group whose every member a reader reads (IPASC's
    ``meta_data``) is 160 MiB decoded from 8 MiB stored. Today's main checked each dataset
    alone (8 MiB, under the limit) and the ratio (1:1); now the sum is refused."""
    from fpscan.service.storage.loader import load_dataset

    path = tmp_path / "links.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("sensor_data", data=np.random.default_rng(4).standard_normal((64, 16)).astype(np.float32))
        f["meta"] = np.random.default_rng(5).standard_normal(2**20)
        for i in range(20):
            f[f"meta_data/m{i}"] = f["meta"]
        f.attrs.update({"dt_s": 1e-8, "dx_m": 1e-4})
    with pytest.raises(ValueError, match="declare .* bytes together .every link counted., more than the limit of"):
        load_dataset(path, "kwave-hdf5", max_bytes=64 * 2**20)
    assert load_dataset(path, "kwave-hdf5", max_bytes=256 * 2**20).data.shape == (64, 16)
