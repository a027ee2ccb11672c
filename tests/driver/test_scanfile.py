"""Scan file (fpscan.driver.scanfile): real HDF5 files, a SIGKILLed writer process, a SWMR reader
in another process, and bad input."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fpscan.driver.plan import plan_id_of
from fpscan.driver.scanfile import META_KEYS, ScanFile, read_scan, superblock_open_for_write
from tests.hdf5_superblock import lookup3, set_status_flags
from tests.waits import HANG_S

REPO = Path(__file__).resolve().parents[2]


def make_plan(n_points: int = 50, n_t: int = 64, two_d: bool = False) -> dict:
    n_x = 16
    n_y = max(16, -(-n_points // n_x))  # enough rows for every point
    idx = [[k % n_x, k // n_x] for k in range(n_points)]
    pitch = 6e-5
    if two_d:
        idx = [[k, 0] for k in range(n_points)]
        pos = [[(i - (n_points - 1) / 2) * pitch] for i, _ in idx]
    else:
        pos = [[(i - (n_x - 1) / 2) * pitch, (j - (n_y - 1) / 2) * pitch] for i, j in idx]
    plan = {
        "format": "fpscan-plan/1",
        "lattice": {"n_x": n_x if not two_d else n_points, "n_y": n_y if not two_d else 1,
                    "pitch": pitch},
        "mask": {"kind": "user", "params": {}},
        "points": {"indices": idx, "positions": pos,
                   "weights": [pitch * pitch * (1 + 0.01 * k) for k in range(n_points)]},
        "order": "serpentine",
        "acquisition": {"n_t": n_t, "dt": 8e-9, "averages": 1, "wavelengths": [7.5e-7],
                        "prf": 0.0, "sound_speed": 1480.0},
    }
    plan["id"] = plan_id_of(plan)
    return plan


def aline(k: int, n_t: int) -> np.ndarray:
    """Deterministic int16 samples of point k (the oracle both writers use)."""
    return np.random.default_rng(1000 + k).integers(-32768, 32767, n_t, dtype=np.int16,
                                                    endpoint=True)


def meta(k: int) -> dict:
    return dict(run_id=7, boot_id=3 + k % 2, point_index=k, pulse_number=10 * k,
                timestamp_s=0.02 * k, bias_wavelength_m=1.55e-6 + 1e-12 * k,
                dc_level=0.5 + 0.001 * k, pulse_energy_j=1e-3, dt_s=8e-9,
                scale=1e-4 * (1 + k % 3), offset=-2e-3 * (k % 5))


INSTRUMENT = {"idn": "fpscan,simFP,0001,1.0"}


def test_write_read_roundtrip(tmp_path):
    plan = make_plan(50, 64)
    path = tmp_path / "scan.h5"
    order = np.random.default_rng(0).permutation(50)[:40]
    with ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="9.9") as sf:
        assert (sf.plan_id, sf.n_points, sf.n_t) == (plan["id"], 50, 64)
        assert not sf.completed().any()
        for k in order:
            assert sf.append(int(k), aline(int(k), 64), meta(int(k))) is True
        # duplicates are refused and change nothing
        assert sf.append(int(order[0]), np.zeros(64, np.int16), meta(int(order[0]))) is False
        assert sf.completed().sum() == 40
    d = read_scan(path)
    assert d.plan == plan and d.plan_id == plan["id"]
    assert (d.n_points, d.n_t, d.dt, d.sound_speed) == (50, 64, 8e-9, 1480.0)
    np.testing.assert_array_equal(d.wavelengths, [7.5e-7])
    assert d.instrument == INSTRUMENT and d.software_version == "9.9"
    np.testing.assert_array_equal(d.positions, np.array(plan["points"]["positions"]))
    np.testing.assert_array_equal(d.indices, np.array(plan["points"]["indices"]))
    np.testing.assert_array_equal(d.weights, np.array(plan["points"]["weights"]))
    expected_done = np.zeros(50, bool)
    expected_done[order] = True
    np.testing.assert_array_equal(d.completed, expected_done)
    for k in range(50):
        if expected_done[k]:
            np.testing.assert_array_equal(d.alines[k], aline(k, 64))
            m = meta(k) | {"wavelength_index": 0, "excitation_wavelength_m": 7.5e-7}  # defaults
            for key in META_KEYS:
                assert d.meta[key][k] == m[key], key
            p = (aline(k, 64).astype(np.float64) * m["scale"] + m["offset"]) / m["dc_level"]
            np.testing.assert_allclose(d.pressure[k], p, rtol=1e-15, atol=0)
        else:
            assert np.isnan(d.pressure[k]).all() and not d.alines[k].any()
    sub = d.completed_only()
    assert sub.n_points == 40 and sub.completed.all()
    np.testing.assert_array_equal(sub.positions, d.positions[np.sort(order)])
    f32 = read_scan(path, dtype=np.float32).pressure
    assert f32.dtype == np.float32
    np.testing.assert_allclose(f32[expected_done], d.pressure[expected_done], rtol=1e-6)


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=st.lists(st.tuples(st.integers(0, 9), st.integers(0, 3)), max_size=40),
       reopen_at=st.integers(0, 40))
def test_any_append_sequence_matches_a_dict_model(tmp_path_factory, ops, reopen_at):
    """Random appends (with duplicates and a close/reopen in between) against a plain dict:
    the first A-line appended for a point is the one kept; later ones are refused."""
    path = tmp_path_factory.mktemp("h") / "m.h5"
    plan = make_plan(10, 8)
    model: dict[int, np.ndarray] = {}
    sf = ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="1")
    try:
        for i, (k, variant) in enumerate(ops):
            if i == reopen_at:
                sf.close()
                sf = ScanFile.open_append(path, plan)
            x = aline(k + 100 * variant, 8)
            assert sf.append(k, x, meta(k)) is (k not in model)
            model.setdefault(k, x)
            np.testing.assert_array_equal(sf.completed(), [j in model for j in range(10)])
    finally:
        sf.close()
    d = read_scan(path)
    np.testing.assert_array_equal(d.completed, [j in model for j in range(10)])
    for k, x in model.items():
        np.testing.assert_array_equal(d.alines[k], x)
        assert d.meta["pulse_number"][k] == meta(k)["pulse_number"]


def test_2d_plan_and_resume_in_process(tmp_path):
    plan = make_plan(12, 32, two_d=True)
    path = tmp_path / "line.h5"
    with ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="1") as sf:
        for k in range(5):
            sf.append(k, aline(k, 32), meta(k))
    assert not (tmp_path / "line.h5.lock").exists()
    with ScanFile.open_append(path, plan) as sf:
        np.testing.assert_array_equal(sf.completed(), np.arange(12) < 5)
        assert sf.append(3, aline(3, 32), meta(3)) is False
        for k in range(5, 12):
            assert sf.append(k, aline(k, 32), meta(k))
    d = read_scan(path)
    assert d.positions.shape == (12, 1) and d.completed.all()
    np.testing.assert_array_equal(d.alines, np.stack([aline(k, 32) for k in range(12)]))


def test_fsync_policy_and_reader_in_the_writing_process(tmp_path):
    plan = make_plan(20, 16)
    path = tmp_path / "fs.h5"
    with ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="1",
                         durable="fsync") as sf:
        for k in range(0, 20, 2):
            assert sf.append(k, aline(k, 16), meta(k))
        d = read_scan(path)  # same process, file still open for writing
        np.testing.assert_array_equal(d.completed, np.arange(20) % 2 == 0)
        np.testing.assert_array_equal(d.alines[4], aline(4, 16))
        assert sf.append(1, aline(1, 16), meta(1))  # the writer is unaffected by the reader
    assert read_scan(path).completed.sum() == 11


def test_resume_waits_for_a_reader_holding_the_file(tmp_path):
    plan = make_plan(8, 16)
    path = tmp_path / "held.h5"
    with ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="1") as sf:
        sf.append(0, aline(0, 16), meta(0))
    holder = subprocess.Popen(  # holds the file open until its stdin closes (not for a time)
        [sys.executable, "-c", "import sys, h5py\n"
         "f = h5py.File(sys.argv[1], 'r', libver='latest', swmr=True)\n"
         "print('open', flush=True); sys.stdin.read(); f.close()", str(path)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        with pytest.raises(ValueError, match="lock"):
            ScanFile.open_append(path, plan, timeout=0.1)
        import threading

        threading.Timer(1.0, holder.stdin.close).start()  # the reader lets go while we wait
        with ScanFile.open_append(path, plan, timeout=HANG_S) as sf:  # waits for the reader
            assert sf.append(1, aline(1, 16), meta(1))
    finally:
        holder.kill()
        holder.wait(timeout=30)
    np.testing.assert_array_equal(read_scan(path).completed, np.arange(8) < 2)


WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from tests.driver.test_scanfile import aline, meta, make_plan, INSTRUMENT
    from fpscan.driver.scanfile import ScanFile
    path, n, n_t, delay = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
    import os
    plan = make_plan(n, n_t)
    if os.path.exists(path):  # a killed run before: resume from its record
        sf = ScanFile.open_append(path, plan)
    else:
        sf = ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="1")
    print("ready", flush=True)
    for k in np.flatnonzero(~sf.completed()):
        k = int(k)
        assert sf.append(k, aline(k, n_t), meta(k))
        # acknowledged: append() returned. Lines are padded so that the 64 kB pipe fills
        # after a few hundred unread acks: the writer cannot finish before it is killed.
        print(str(k).ljust(120), flush=True)
        if delay:
            time.sleep(delay)
    sf.close()
    print("done", flush=True)
""")


def test_sigkill_then_resume_equals_uninterrupted(tmp_path):
    n, n_t = 3000, 64
    path = tmp_path / "killed.h5"
    acked = -1
    for _ in range(2):  # kill a fresh writer, then kill the writer that resumed its file
        start = acked
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(n), str(n_t), "0"],
                                stdout=subprocess.PIPE, text=True, cwd=REPO)
        try:
            deadline = time.monotonic() + HANG_S
            for line in proc.stdout:
                if line.strip().isdigit():
                    acked = int(line)
                    if acked >= start + 300:
                        os.kill(proc.pid, signal.SIGKILL)
                        break
                assert time.monotonic() < deadline, "writer too slow"
        finally:
            proc.kill()
            proc.wait(timeout=30)
        assert proc.returncode == -signal.SIGKILL and acked >= start + 300
    # a plain (non-SWMR) open is refused until the writer's flags are cleared ...
    with pytest.raises(OSError):
        h5py.File(path, "r")
    # ... but an SWMR reader can read the killed file right away
    partial = read_scan(path)
    assert partial.completed[:acked + 1].all(), "an acknowledged A-line was lost"
    n_done = int(partial.completed.sum())
    assert n_done < n
    with ScanFile.open_append(path, make_plan(n, n_t)) as sf:
        done = sf.completed()
        assert done.sum() == n_done
        for k in np.flatnonzero(~done):
            assert sf.append(int(k), aline(int(k), n_t), meta(int(k)))
        assert sf.append(0, aline(0, n_t), meta(0)) is False
    ref = tmp_path / "ref.h5"
    with ScanFile.create(ref, make_plan(n, n_t), instrument=INSTRUMENT,
                         software_version="1") as sf:
        for k in range(n):
            sf.append(k, aline(k, n_t), meta(k))
    a, b = read_scan(path), read_scan(ref)
    assert a.completed.all() and b.completed.all()
    np.testing.assert_array_equal(a.alines, b.alines)
    for key in META_KEYS:
        np.testing.assert_array_equal(a.meta[key], b.meta[key])
    np.testing.assert_array_equal(a.pressure, b.pressure)
    assert a.plan == b.plan
    with h5py.File(path, "r") as f:  # closed cleanly now: ordinary readers work again
        assert f["completed"][()].all()


READER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from tests.driver.test_scanfile import aline
    from fpscan.driver.scanfile import read_scan
    path, n_t = sys.argv[1], int(sys.argv[2])
    last, reads, seen = -1, 0, []
    read_scan(path)
    print("ready", flush=True)
    while True:  # until every point is read (no clock: the test's timeout bounds it)
        d = read_scan(path)
        done = np.flatnonzero(d.completed)
        assert len(done) >= last, "completed count went backwards"
        for k in done:
            assert (d.alines[k] == aline(int(k), n_t)).all(), f"torn A-line {{k}}"
        if len(done) != last:
            print("seen", len(done), flush=True)  # the writer waits for this
        last = len(done); reads += 1; seen.append(last)
        if last == d.n_points:
            break
        time.sleep(0.01)
    print(reads, len(set(seen)), last, flush=True)
""")


def test_swmr_reader_in_other_process_while_writing(tmp_path):
    n, n_t = 400, 128
    path = tmp_path / "live.h5"
    plan = make_plan(n, n_t)
    with ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="1") as sf:
        proc = subprocess.Popen([sys.executable, "-c", READER, str(path), str(n_t)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=REPO)
        try:
            assert proc.stdout.readline().strip() == "ready"  # reader up before we write
            for k in range(n):
                sf.append(k, aline(k, n_t), meta(k))
                if k % 20 == 19 and k < n - 1:  # a batch written: on once the reader has seen it
                    while int((line := proc.stdout.readline() or "seen -1").split()[1]) < k + 1:
                        assert line.startswith("seen") and proc.poll() is None, f"reader gone: {line!r}"
            out, err = proc.communicate()
        finally:
            proc.kill()
    assert proc.returncode == 0, err
    reads, distinct, last = map(int, out.split()[-3:])
    assert last == n
    assert distinct >= n // 20, f"the reader saw only {distinct} distinct states in {reads} reads"


def test_lookup3_known_vectors_and_superblock(tmp_path):
    # test vectors from Bob Jenkins' lookup3.c (driver5), for the tests' own checksum
    assert lookup3(b"") == 0xDEADBEEF
    assert lookup3(b"Four score and seven years ago") == 0x17770551
    assert lookup3(b"Four score and seven years ago", 1) == 0xCD628161
    path = tmp_path / "x.h5"
    with h5py.File(path, "w", libver="latest") as f:
        f["a"] = np.arange(3)
    assert superblock_open_for_write(path) is False  # checksum of HDF5's own superblock verified
    src = bytearray(path.read_bytes())
    set_status_flags(src)  # checksum by the tests' lookup3: the reader's agrees
    flagged = tmp_path / "flagged.h5"
    flagged.write_bytes(bytes(src))
    assert superblock_open_for_write(flagged) is True
    src[11] = 0  # flags changed, checksum not
    flagged.write_bytes(bytes(src))
    with pytest.raises(ValueError, match="corrupt or truncated HDF5 superblock"):
        superblock_open_for_write(flagged)
    (tmp_path / "junk.h5").write_bytes(b"not hdf5 at all" * 10)
    with pytest.raises(ValueError, match="not an HDF5"):
        superblock_open_for_write(tmp_path / "junk.h5")


def test_bad_input(tmp_path):
    plan = make_plan(10, 16)
    path = tmp_path / "bad.h5"
    with pytest.raises(ValueError, match="does not match its content"):
        ScanFile.create(path, dict(plan, id="0" * 64), instrument={}, software_version="1")
    bad = json.loads(json.dumps(plan))
    bad["acquisition"]["n_t"] = 0
    bad["id"] = plan_id_of(bad)
    with pytest.raises(ValueError, match="n_t"):
        ScanFile.create(path, bad, instrument={}, software_version="1")
    bad = json.loads(json.dumps(plan))
    bad["points"]["weights"] = bad["points"]["weights"][:-1]
    bad["id"] = plan_id_of(bad)
    with pytest.raises(ValueError, match="weights"):
        ScanFile.create(path, bad, instrument={}, software_version="1")
    with pytest.raises(ValueError, match="durable"):
        ScanFile.create(path, plan, instrument={}, software_version="1", durable="maybe")
    assert not path.exists()

    sf = ScanFile.create(path, plan, instrument={}, software_version="1")
    try:
        x = aline(0, 16)
        for args, what in [
            ((0, x[:-1], meta(0)), "shape"),
            ((0, x.astype(np.float64), meta(0)), "int16"),
            ((0, x.astype(np.int32), meta(0)), "int16"),
            ((0, list(x), meta(0)), "numpy"),
            ((10, x, meta(10)), "out of range"),
            ((-1, x, meta(-1)), "out of range"),
            ((True, x, meta(1)), "integer"),
            ((1, x, meta(0)), "point_index"),
            ((0, x, {k: v for k, v in meta(0).items() if k != "scale"}), "missing"),
            ((0, x, dict(meta(0), colour="red")), "unknown"),
            ((0, x, dict(meta(0), dc_level=0.0)), "dc_level"),
            ((0, x, dict(meta(0), scale=float("nan"))), "scale"),
            ((0, x, dict(meta(0), run_id=-1)), "run_id"),
            ((0, x, dict(meta(0), timestamp_s="soon")), "timestamp_s"),
        ]:
            with pytest.raises(ValueError, match=what):
                sf.append(*args)
        assert not sf.completed().any()  # nothing was written by the refused appends
        with pytest.raises(ValueError, match="another process"):
            ScanFile.open_append(path)
        with pytest.raises(FileExistsError):
            ScanFile.create(path, plan, instrument={}, software_version="1")
    finally:
        sf.close()
    with pytest.raises(RuntimeError):
        sf.append(0, aline(0, 16), meta(0))
    other = make_plan(11, 16)
    with pytest.raises(ValueError, match="does not match"):
        ScanFile.open_append(path, other)
    with ScanFile.open_append(path, plan):  # the refused resume released its lock
        pass
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w", libver="latest") as f:
        f["x"] = 1
    with pytest.raises(ValueError, match="not an fpscan-scan"):
        read_scan(plain)
    with pytest.raises(ValueError, match="not an fpscan-scan"):
        ScanFile.open_append(plain)
    with pytest.raises(FileNotFoundError):
        read_scan(tmp_path / "missing.h5")
    with pytest.raises(ValueError, match="float"):
        read_scan(path, dtype=np.int32)


def _replaced(name: str, cut):
    def edit(f: h5py.File) -> None:
        data = cut(f[name][()])
        del f[name]
        f[name] = data
    return edit


@pytest.mark.parametrize("edit, what", [
    (_replaced("alines", lambda a: a[..., :8]), "/alines has shape (1, 10, 8)"),
    (_replaced("alines", lambda a: np.concatenate([a, a], axis=-1)), "/alines has shape (1, 10, 32)"),
    (_replaced("alines", lambda a: a[0]), "/alines has shape (10, 16)"),
    (_replaced("completed", lambda a: a[:, :5]), "/completed has shape (1, 5)"),
    (_replaced("aline_meta", lambda a: a[:, :5]), "/aline_meta has shape (1, 5)"),
    (_replaced("positions", lambda a: a[:5]), "/positions has shape (5, 2)"),
    (_replaced("indices", lambda a: a[:5]), "/indices has shape (5, 2)"),
    (_replaced("weights", lambda a: a[:5]), "/weights has shape (5,)"),
    (lambda f: f.attrs.__setitem__("n_t", 8), "n_t = 8"),
    (lambda f: f.attrs.__setitem__("n_points", 5), "n_points = 5"),
    (lambda f: f.attrs.__setitem__("n_points", -5), "positive integers"),
    (lambda f: f.attrs.__setitem__("wavelengths_m", [7.5e-7, 8e-7]), "2 wavelength(s)"),
    (lambda f: f.__delitem__("weights"), "no dataset /weights"),
], ids=["alines-short", "alines-long", "alines-2d", "completed", "meta", "positions", "indices", "weights",
        "n_t-attr", "n_points-attr", "n_points-negative", "wavelengths-attr", "no-weights"])
def test_a_file_whose_arrays_disagree_with_its_attributes_is_refused(tmp_path, edit, what):
    """A scan file is hostile input: one whose datasets do not have the shapes its own n_points,
    n_t and wavelengths give (docs/file-formats.md) is refused with the shapes named, rather
    than read as another record (A-lines shorter than n_t read as a shorter scan) or failing
    deep inside the reader with an IndexError."""
    plan = make_plan(10, 16)
    path = tmp_path / "scan.h5"
    with ScanFile.create(path, plan, instrument=INSTRUMENT, software_version="1") as sf:
        for k in range(10):
            sf.append(k, aline(k, 16), meta(k))
    assert read_scan(path).alines.shape == (10, 16)  # as written, it reads
    with h5py.File(path, "r+") as f:
        edit(f)
    with pytest.raises(ValueError) as exc:
        read_scan(path)
    assert what in str(exc.value), str(exc.value)
