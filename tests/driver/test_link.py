"""The scanner link end to end: host driver ↔ simulated FP scanner on a real pty, real
scan files (fpscan.driver.scanfile), ground truth from the simulator's own HDF5 record."""
from __future__ import annotations

import math
import os
import threading
import time

import numpy as np
import pytest

from fpscan.driver.acquire import acquire
from fpscan.driver.faults import FaultSpec
from fpscan.driver.host import DeviceError, DriverError, InterlockOpen, Scanner
from fpscan.driver.scanfile import ScanFile, read_scan
from fpscan.driver.simulator import SimConfig, SimulatedScanner
from fpscan.driver.sources import BallSource, ReplaySource
from tests.driver.driver_helpers import grid_plan, read_record, small_phantom
from tests.waits import HANG_S

# mostly real time on a pty (PRF pacing, link timeouts): run in scripts/test.sh's `waits` lane
pytestmark = [pytest.mark.timeout(120), pytest.mark.waits]


def make_sim(tmp_path, **kw) -> SimulatedScanner:
    kw.setdefault("source", BallSource(small_phantom()))
    kw.setdefault("prf", 0.0)
    kw.setdefault("record", tmp_path / "truth.h5")
    return SimulatedScanner(SimConfig(**kw))


def assert_matches_record(scan_path, record_path, plan):
    scan = read_scan(scan_path)
    samples, scale, dc, sent = read_record(record_path, plan["id"])
    assert scan.completed_all.all() and sent.all()
    assert np.array_equal(scan.alines_all, samples)  # bit-identical int16, every wavelength
    assert np.array_equal(scan.meta_all["scale"], scale)
    assert np.array_equal(scan.meta_all["dc_level"], dc)
    n_w, n = sent.shape
    assert np.array_equal(scan.meta_all["point_index"], np.tile(np.arange(n), (n_w, 1)))
    assert np.array_equal(scan.meta_all["wavelength_index"], np.repeat(np.arange(n_w)[:, None], n, 1))
    return scan


def test_fault_scan_every_aline_once_and_bit_identical(tmp_path):
    plan = grid_plan(41, 40, n_t=256)  # 1640 points
    n = len(plan["points"]["indices"])
    faults = FaultSpec.parse("corrupt=1e-4,drop=1e-4,stall=500:2.0,reset=1100")
    appended = []

    class CountingFile(ScanFile):
        def append(self, k, samples, meta):
            ok = super().append(k, samples, meta)
            appended.append((k, ok))
            return ok

    with make_sim(tmp_path, faults=faults, seed=11) as sim:
        with Scanner(sim.path, response_timeout=10) as sc:
            sink = CountingFile.create(tmp_path / "scan.h5", plan, instrument=sc.identify(),
                                       software_version="test")
            with sink:
                res = sc.scan(plan, sink)
        stats = dict(sim.stats)
    print("faults seen by the host:", res.faults, res.link, "device:", stats)
    assert res.faults_recovered == sum(res.faults.values()) > 0 and res.alines_received >= n
    assert res.complete and res.points_done == n
    # every point appended exactly once, none refused as duplicate
    ks = [k for k, ok in appended]
    assert sorted(ks) == list(range(n)) and all(ok for _, ok in appended)
    # the faults really happened and were recovered
    assert stats["resets"] == 1 and stats["stalls"] == 1
    assert res.faults["resets"] == 1 and res.faults["bad_frames"] > 10
    assert res.faults["naks"] > 0 and res.faults["stall_polls"] >= 1
    assert_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)


def test_prf_timing_100_points_at_50_hz(tmp_path):
    plan = grid_plan(10, 10, n_t=256)
    with make_sim(tmp_path, prf=50.0) as sim:
        with Scanner(sim.path) as sc:
            sc.identify()
            sc.upload_plan(plan)
            with ScanFile.create(tmp_path / "scan.h5", plan, instrument={}, software_version="t") as sf:
                res = sc.scan(plan, sf, upload=False)
    # timed window: SCAN:STAR reply → last A-line (nothing else runs in between)
    print(f"100 points at 50 Hz: acquisition took {res.acquisition_s:.4f} s (ideal 2.0 s)")
    assert res.complete
    assert 1.9 <= res.acquisition_s <= 2.1
    ts = read_scan(tmp_path / "scan.h5").meta["timestamp_s"]
    assert np.allclose(np.diff(ts), 0.02, atol=1e-9)  # one pulse per PRF tick


def test_pause_resume_abort_from_another_thread(tmp_path):
    plan = grid_plan(30, 30, n_t=128)  # 900 points at 200 Hz: 4.5 s if never stopped
    seen = []
    with make_sim(tmp_path, prf=200.0) as sim, Scanner(sim.path) as sc:
        sf = ScanFile.create(tmp_path / "scan.h5", plan, instrument={}, software_version="t")
        out = {}
        th = threading.Thread(target=lambda: out.setdefault(
            "res", sc.scan(plan, sf, progress=seen.append, progress_interval=0.05)))
        th.start()
        deadline = time.monotonic() + HANG_S
        while (not seen or seen[-1].points_done < 50) and time.monotonic() < deadline:
            time.sleep(0.02)
        sc.pause()
        # the device stops before it answers SCAN:PAUS, and the link is FIFO: once the
        # host reports "paused" no further A-line can arrive
        while seen[-1].state != "paused" and time.monotonic() < deadline:
            time.sleep(0.02)
        done_paused = seen[-1].points_done
        time.sleep(0.5)
        assert seen[-1].points_done == done_paused and seen[-1].state == "paused"
        # a pause is not acquiring time: while paused the rate holds (it fell with every report) and
        # no end is predicted (the ETA grew)
        while sum(p.state == "paused" for p in seen) < 3 and time.monotonic() < deadline:  # reports, not a clock
            time.sleep(0.02)
        paused = [p for p in seen if p.state == "paused"]
        assert len(paused) >= 2 and all(math.isinf(p.eta_s) for p in paused), paused
        assert max(p.rate for p in paused) == pytest.approx(min(p.rate for p in paused), rel=1e-9), paused
        sc.resume()
        while seen[-1].points_done < done_paused + 50 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert seen[-1].points_done >= done_paused + 50
        sc.abort()
        th.join(timeout=HANG_S)
        assert not th.is_alive()
        res = out["res"]
        assert res.aborted and not res.complete and 100 <= res.points_done < 900
        assert sc.status().state == "IDLE"  # the device is left idle
        sf.close()
    p = seen[-1]
    assert p.state == "aborted" and p.n_points == 900 and p.rate > 0
    assert read_scan(tmp_path / "scan.h5").completed.sum() == res.points_done


def test_an_interlock_event_the_device_state_denies_does_not_stop_the_scan(tmp_path):
    """Events are hints (docs/protocol.md §9.3): an ``EVENT INTERLOCK 1`` from a device whose state is
    RUNNING (the interlock closed) is checked with ``SCAN:STAT?`` and the scan goes on to the end
    (it stopped with "Laser interlock open", a false reason, at that A-line)."""
    plan = grid_plan(6, 5, n_t=64)
    # the stall holds A-line 5 back 0.5 s, so that the event comes within the run the host follows
    # (an event that overtakes the SCAN:STAR reply has no run to be about)
    with make_sim(tmp_path, faults=FaultSpec.parse("stall=5:0.5,event=5:INTERLOCK 1")) as sim:
        res = acquire(sim.path, plan, tmp_path / "scan.h5")
        assert sim.stats["false_events"] == 1
    assert res.complete and res.points_done == 30
    assert_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)


def test_interlock_stops_scan_with_clear_error(tmp_path):
    plan = grid_plan(20, 10, n_t=128)
    with make_sim(tmp_path, faults=FaultSpec.parse("interlock=120")) as sim:
        with pytest.raises(InterlockOpen, match="interlock"):
            acquire(sim.path, plan, tmp_path / "scan.h5", response_timeout=5)
        with Scanner(sim.path) as sc:
            assert sc.status().state == "FAULT"
            assert sc.query("LAS:INT?") == "1"
            assert (101, "Laser interlock open") in sc.errors()
    done = read_scan(tmp_path / "scan.h5").completed
    assert done[:120].all() and not done[120:].any()


def test_replay_kwave_data_within_quantisation(tmp_path, shared_data):
    import h5py

    from fpscan.driver.plan import plan_id_of

    path = shared_data / "kwave3d_balls_yarn.h5"
    with h5py.File(path) as f:
        ref = np.asarray(f["sensor_data/clean"], dtype=np.float64)  # (t, y, x)
        dt = float(f.attrs["dt_s"])
    full = grid_plan(96, 96, 6e-5, n_t=ref.shape[0], dt=dt)  # every stored A-line
    # a 48 x 48 lattice centred on the same axis: point (i, j) is stored (i + 24, j + 24)
    inner = grid_plan(48, 48, 6e-5, n_t=500, dt=dt)
    keep = list(range(0, 48 * 48, 37))
    for key in ("indices", "positions", "weights"):
        inner["points"][key] = [inner["points"][key][i] for i in keep]
    inner["id"] = plan_id_of(inner)
    with make_sim(tmp_path, source=ReplaySource(path)) as sim:
        assert acquire(sim.path, full, tmp_path / "full.h5").complete
        assert acquire(sim.path, inner, tmp_path / "inner.h5").complete
    for name, plan, off in [("full", full, 0), ("inner", inner, 24)]:
        scan = read_scan(tmp_path / f"{name}.h5")
        idx = np.asarray(plan["points"]["indices"]) + off
        want = ref[:scan.n_t, idx[:, 1], idx[:, 0]].T  # (n_points, n_t)
        err = np.abs(scan.pressure - want)
        assert (err <= scan.scale[:, None] * 0.5 * (1 + 1e-6) + 1e-7 * np.abs(want)).all()
        assert np.abs(want).max() > 1000 * scan.scale.max()  # the check is not vacuous
        print(f"replay {name}: {len(idx)} A-lines, max error {err.max():.3g} vs max "
              f"half-step {0.5 * scan.scale.max():.3g}")


def test_bad_input_gives_clear_errors_never_hangs(tmp_path):
    with pytest.raises(DriverError, match="cannot open"):
        Scanner(str(tmp_path / "no-such-port"))
    plan = grid_plan(20, 20, n_t=64)  # 400 points
    with make_sim(tmp_path, max_points=300, max_samples=4096) as sim:
        with Scanner(sim.path, response_timeout=3) as sc:
            with pytest.raises(DriverError, match="cannot open"):
                Scanner(sim.path, lock_timeout=0.3)  # busy: exclusively locked by sc
            assert sc.query("*IDN?").startswith("fpscan,FP-SIM,")
            with pytest.raises(DeviceError) as e:
                sc.query("SCAN:FROB 3")
            assert e.value.code == -113
            with pytest.raises(DeviceError) as e:
                sc.query("SCAN:STAR 0")
            assert e.value.code == 103  # no plan
            with pytest.raises(DeviceError) as e:
                sc.upload_plan(plan)  # 400 points > the device's 300
            assert e.value.code == -222
            with pytest.raises(DeviceError) as e:
                sc.query(b"PLAN:DATA 0,#3999ab")
            assert e.value.code == -161
            with pytest.raises(DeviceError) as e:
                sc.query("PLAN:END " + "0" * 64)
            assert e.value.code == -200
            small = grid_plan(10, 10, n_t=64)
            sc.upload_plan(small)
            with pytest.raises(DeviceError) as e:
                sc.query("SCAN:STAR 100")  # out of range: points 0..99
            assert e.value.code == -222
            # raw garbage and a frame with a bad CRC on the wire: dropped, queued, survived
            sc._write(b"\x01\x02garbage\xff\x00" + b"\x55" * 300 + b"\x00")
            codes = [c for c, _ in sc.errors()]
            assert -113 in codes and 103 in codes and -222 in codes and -310 in codes
            assert sc.query("*OPC?") == "1"
            assert sc.query("PLAN:ID?") == small["id"]
            with pytest.raises(ValueError, match="outside the lattice"):
                bad = grid_plan(10, 10)
                bad["points"]["indices"][0] = [10, 0]
                sc.upload_plan(bad)
        # the simulator is still alive and serves a new host
        with Scanner(sim.path) as sc2:
            assert sc2.status().state == "IDLE"
    # a port that exists but never answers: a timeout, not a hang
    import pty

    master, slave = pty.openpty()
    try:
        with Scanner(os.ttyname(slave), response_timeout=1.0) as sc3:
            with pytest.raises(DriverError, match="no reply"):
                sc3.query("*IDN?")
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("reader", ["thread", "direct"])
def test_other_reader_modes(tmp_path, reader):
    plan = grid_plan(15, 10, n_t=128)
    with make_sim(tmp_path, faults=FaultSpec.parse("corrupt=2e-4"), seed=2) as sim:
        with Scanner(sim.path, reader=reader) as sc:
            with ScanFile.create(tmp_path / "scan.h5", plan, instrument=sc.identify(),
                                 software_version="t") as sf:
                assert sc.scan(plan, sf).complete
    assert_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)
    with pytest.raises(ValueError, match="reader"):
        Scanner(sim.path, reader="telepathy")


def test_tuning_delay_and_averages_follow_the_pulse_clock(tmp_path):
    # 100 Hz laser, 15 ms bias tuning per point, 2 pulses averaged per point: each point
    # waits for the 2nd tick after the previous one and then uses 2 ticks -> 30 ms apart
    plan = grid_plan(5, 4, n_t=64, averages=2)
    with make_sim(tmp_path, prf=100.0, tuning_delay=0.015) as sim:
        res = acquire(sim.path, plan, tmp_path / "scan.h5")
    assert res.complete
    meta = read_scan(tmp_path / "scan.h5").meta
    assert np.allclose(np.diff(meta["timestamp_s"]), 0.030, atol=1e-9)
    assert np.array_equal(np.diff(meta["pulse_number"]), np.full(19, 2))


def test_device_survives_random_commands_and_frames(tmp_path):
    import zlib

    from cobs import cobs

    from fpscan.driver.framing import HEADER, FrameType, encode_frame

    rng = np.random.default_rng(4)
    words = ["*IDN?", "*RST", "SCAN:STAR", "SCAN:STAT?", "PLAN:DATA", "PLAN:BEG", "PLAN:END",
             "SYST:ERR?", "SCAN:PAUS", "SCAN:RES", "PLAN:ID?", "LAS:INT?", ":syst:lim?"]
    with make_sim(tmp_path) as sim, Scanner(sim.path, response_timeout=3) as sc:
        sc.upload_plan(grid_plan(6, 6, n_t=32))
        replies = errors = 0
        for i in range(150):
            if i % 3 == 0:
                cmd = bytes(rng.integers(0, 256, rng.integers(0, 40)).astype(np.uint8))
            else:
                args = ",".join(str(int(x)) for x in rng.integers(-5, 10**6, rng.integers(0, 3)))
                cmd = f"{words[rng.integers(len(words))]} {args}".encode()
            try:
                sc.query(cmd)
                replies += 1
            except DeviceError:
                errors += 1
        assert replies + errors == 150 and errors > 20 and replies > 10
        # well-formed frames the device must refuse: wrong version, unknown type, and a
        # frame type only the device sends
        for version, ftype in [(2, 1), (1, 99), (1, int(FrameType.ALINE))]:
            body = HEADER.pack(version, ftype, 0, 1, 0) + b"*IDN?"
            sc._write(cobs.encode(body + zlib.crc32(body).to_bytes(4, "little")) + b"\x00")
        sc._write(encode_frame(FrameType.NAK, b"\x01\x02\x03"))  # ragged NAK list
        sc.query("SCAN:ABOR")
        sc.query("*CLS")
        sc._write(encode_frame(FrameType.ALINE, b"\x00" * 80, seq=5))
        assert sc.query("*IDN?").startswith("fpscan,")
        assert any(c == -310 for c, _ in sc.errors())


def test_refused_plan_leaves_no_scan_file(tmp_path):
    plan = grid_plan(20, 20, n_t=64)
    with make_sim(tmp_path, max_points=100) as sim:
        with pytest.raises(DeviceError, match="-222"):
            acquire(sim.path, plan, tmp_path / "scan.h5")
    assert not (tmp_path / "scan.h5").exists()


def test_byte_rate_limit_throttles_the_link(tmp_path):
    # a UART-like link: 20 kB/s. Only a lower bound on the time is asserted (a loaded
    # machine can only make it slower); the rate is printed.
    plan = grid_plan(8, 5, n_t=128)
    with make_sim(tmp_path, byte_rate=20_000.0) as sim, Scanner(sim.path) as sc:
        sc.identify()
        sc.upload_plan(plan)
        tx0 = sim.stats["tx_bytes"]
        with ScanFile.create(tmp_path / "scan.h5", plan, instrument={},
                             software_version="t") as sf:
            res = sc.scan(plan, sf, upload=False)
        sent = sim.stats["tx_bytes"] - tx0
    assert res.complete and sent > 40 * 2 * 128
    print(f"byte-rate limit 20000 B/s: {sent} bytes in {res.acquisition_s:.3f} s "
          f"= {sent / res.acquisition_s:.0f} B/s")
    assert res.acquisition_s >= 0.9 * (sent - 2000) / 20_000.0


def test_scan_survives_the_relay_process_dying(tmp_path):
    plan = grid_plan(20, 10, n_t=128)  # 200 points at 200 Hz
    seen = []
    with make_sim(tmp_path, prf=200.0) as sim, Scanner(sim.path) as sc:
        relay = sc._reader.process
        assert relay is not None and relay.poll() is None
        sf = ScanFile.create(tmp_path / "scan.h5", plan, instrument={}, software_version="t")
        out = {}
        th = threading.Thread(target=lambda: out.setdefault(
            "res", sc.scan(plan, sf, progress=seen.append, progress_interval=0.05)))
        th.start()
        deadline = time.monotonic() + HANG_S
        while (not seen or seen[-1].points_done < 40) and time.monotonic() < deadline:
            time.sleep(0.02)
        relay.kill()
        th.join(timeout=HANG_S)
        sf.close()
        assert out["res"].complete and sc._reader.process is None  # fell back to reading the tty
    assert_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)


def test_plan_upload_over_a_noisy_link_and_chunk_rules(tmp_path):
    from fpscan.driver.commands import block
    from fpscan.driver.plan_image import plan_image

    plan = grid_plan(40, 27, n_t=8)  # 1080 points: a 4.4 kB plan image
    with make_sim(tmp_path, faults=FaultSpec.parse("corrupt=2e-3"), seed=9) as sim:
        res = acquire(sim.path, plan, tmp_path / "scan.h5")
    assert res.complete and res.faults["upload_retries"] > 0  # 4 kB chunks rarely pass
    assert_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)
    image = plan_image(grid_plan(4, 4, n_t=32))
    with make_sim(tmp_path) as sim, Scanner(sim.path) as sc:
        sc.query(f"PLAN:BEG {len(image)}")
        sc.query(b"PLAN:DATA 0," + block(image[:60]))
        sc.query(b"PLAN:DATA 20," + block(image[20:100]))  # overlaps consistently: appended
        with pytest.raises(DeviceError) as e:
            sc.query(b"PLAN:DATA 50," + block(b"\x00" * 60))  # contradicts bytes 50..99
        assert e.value.code == -222
        with pytest.raises(DeviceError) as e:
            sc.query(b"PLAN:DATA 120," + block(image[120:]))  # a hole at 100..119
        assert e.value.code == -222
        sc.query(b"PLAN:DATA 100," + block(image[100:]))
        import hashlib

        sc.query(f"PLAN:END {hashlib.sha256(image).hexdigest()}")
        assert sc.query("PLAN:POIN?") == "16"


def test_pyserial_url_transport(tmp_path):
    """The host reaches the scanner through a pyserial URL (socket://): a TCP bridge to the
    simulator's pty stands in for a networked serial server."""
    import select
    import socket
    import tty

    plan = grid_plan(12, 10, n_t=128)
    with make_sim(tmp_path) as sim:
        server = socket.create_server(("127.0.0.1", 0))
        port = server.getsockname()[1]
        stop = threading.Event()

        def bridge():
            conn, _ = server.accept()
            fd = os.open(sim.path, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(fd)
            try:
                while not stop.is_set():
                    r, _, _ = select.select([conn, fd], [], [], 0.1)
                    if conn in r:
                        data = conn.recv(1 << 16)
                        if not data:
                            break
                        os.write(fd, data)
                    if fd in r:
                        conn.sendall(os.read(fd, 1 << 16))
            finally:
                os.close(fd)
                conn.close()

        th = threading.Thread(target=bridge, daemon=True)
        th.start()
        try:
            res = acquire(f"socket://127.0.0.1:{port}", plan, tmp_path / "scan.h5")
        finally:
            stop.set()
            th.join(timeout=5)
            server.close()
    assert res.complete
    assert_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)


def test_interlock_that_closes_again_lets_a_rerun_finish(tmp_path):
    plan = grid_plan(10, 10, n_t=64)
    with make_sim(tmp_path, faults=FaultSpec.parse("interlock=40:0.3")) as sim:
        with pytest.raises(InterlockOpen):
            acquire(sim.path, plan, tmp_path / "scan.h5")
        with Scanner(sim.path) as sc:
            deadline = time.monotonic() + HANG_S
            while sc.query("LAS:INT?") == "1" and time.monotonic() < deadline:
                time.sleep(0.05)
            assert sc.status().state == "FAULT"  # until the host clears it
        res = acquire(sim.path, plan, tmp_path / "scan.h5")
        assert res.complete and res.points_done == 100
    assert_matches_record(tmp_path / "scan.h5", tmp_path / "truth.h5", plan)


def test_device_running_without_progress_times_out(tmp_path):
    # the laser fires every 20 s: the device answers but delivers nothing; the host gives
    # up after max(3 response timeouts, 10 silences) instead of waiting forever
    from fpscan.driver.host import DeviceTimeout

    plan = grid_plan(4, 4, n_t=64)
    with make_sim(tmp_path, prf=0.05) as sim:
        with Scanner(sim.path, response_timeout=0.5, stall_timeout=0.2) as sc:
            sf = ScanFile.create(tmp_path / "scan.h5", plan, instrument={}, software_version="t")
            with pytest.raises(DeviceTimeout, match="no new A-line"):
                sc.scan(plan, sf)
            sf.close()
            assert sc.status().state == "IDLE"  # left idle
