"""A scanner whose word is bounded beyond its numbers: one that resets over and over, one that
reports a ``max_chunk`` below the protocol's minimum, and one that floods a host that is not
reading (the ``reader="thread"`` mode). Each ends in bounded time and memory with the reason,
the scan file intact and a rerun resuming it. Real simulators and raw pseudo-terminals.

- Resets: one call of ``Scanner.scan`` recovers from ``max_resets`` (default
  ``fpscan.driver.host.MAX_RESETS``, 8) device resets; the next one is a ``DeviceFault`` ("the
  scanner reset 9 times during this scan"), and the host's memory of old boot ids holds at most
  ``max_resets + 1`` of them however many resets one ``Scanner`` meets.
- ``max_chunk``: a device reporting fewer than 64 bytes (``fpscan.driver.commands.MIN_CHUNK``)
  is refused before anything is uploaded; one reporting exactly 64 takes every chunk the host
  sends, retries on a noisy link included.
- A device that ignores ACKs, resending old A-lines for ever (never silent), ends the scan with
  ``DeviceTimeout`` once no new A-line came for the host's no-progress bound.
- Flood: the thread reader holds at most ``THREAD_QUEUE_BYTES`` unread; 256 MiB sent to a host
  that is not reading leave its resident size within 50 MB of what it was (the host runs in a
  child process whose resident size this process watches, as in test_device_faults.py), and its
  next read ends as a lost device with the reason.
"""
from __future__ import annotations

import json
import os
import pty
import queue
import subprocess
import sys
import threading
import time
import tty

import numpy as np
import pytest

from fpscan.driver.acquire import acquire
from fpscan.driver.commands import MIN_CHUNK
from fpscan.driver.faults import FaultSpec
from fpscan.driver.host import MAX_IDLE_RUNS, MAX_RESETS, DeviceFault, DeviceTimeout, Scanner
from fpscan.driver.scanfile import ScanFile, read_scan
from fpscan.driver.transport import THREAD_QUEUE_BYTES
from tests.driver.driver_helpers import grid_plan
from tests.driver.test_device_faults import GROWTH
from tests.driver.test_link import assert_matches_record, make_sim
from tests.rss import MB, ROOT, RssWatch
from tests.waits import HANG_S

pytestmark = [pytest.mark.timeout(300)]


def test_a_scanner_that_resets_over_and_over_is_a_device_fault(tmp_path):
    """A device that resets every time it comes to A-line 30 (18 times in all): each call of
    ``scan`` recovers from 8 resets and stops at the 9th with a ``DeviceFault`` (the device left
    idle, the file holding what came before); the boot ids remembered stay at most 9; once the
    device resets no more, a third call completes the file bit for bit."""
    plan = grid_plan(10, 10, n_t=64)
    n, at = 100, 30
    faults = FaultSpec.parse(f"reset={at}:{2 * (MAX_RESETS + 1)}")
    out = tmp_path / "scan.h5"
    with make_sim(tmp_path, faults=faults, seed=3) as sim:
        with Scanner(sim.path) as sc:
            assert sc.max_resets == MAX_RESETS == 8
            sink = ScanFile.create(out, plan, instrument=sc.identify(), software_version="test")
            with sink:
                for call in (1, 2):
                    with pytest.raises(DeviceFault) as info:
                        sc.scan(plan, sink)
                    msg = str(info.value)
                    assert msg.startswith(f"device fault: the scanner reset {MAX_RESETS + 1} times during "
                                          f"this scan; the host recovers from {MAX_RESETS}"), msg
                    # what the device sent before its resets (those in its output buffer when it
                    # reset are lost with it): a prefix of the plan
                    done = int(sink.completed().sum())
                    assert 0 < done <= at and np.array_equal(sink.completed(), np.arange(n) < done)
                    assert f"{done} of {n} A-lines are on disk, re-run to resume" in msg, msg
                    assert sim.stats["resets"] == call * (MAX_RESETS + 1)
                    assert sim.state == "IDLE"
                    assert len(sc._old_boots) <= MAX_RESETS + 1  # 9 and 18 boots met: 9 kept
                res = sc.scan(plan, sink)  # the device resets no more
            assert res.complete and res.points_done == n
            assert sim.stats["resets"] == 2 * (MAX_RESETS + 1)
    assert_matches_record(out, tmp_path / "truth.h5", plan)


def test_a_scanner_that_ends_its_runs_early_is_restarted_then_a_device_fault(tmp_path):
    """A device that ends its run (IDLE, A-lines missing) each time it comes to A-line 12: the host
    restarts it from the first missing A-line, and after MAX_IDLE_RUNS runs in a row that bring no new
    A-line ends the scan with a ``DeviceFault`` (it restarted for ever); a device that ends its run there
    only twice is restarted and completes the file bit for bit."""
    plan = grid_plan(6, 5, n_t=64)
    out = tmp_path / "scan.h5"
    with make_sim(tmp_path, faults=FaultSpec.parse("stop=12:1000"), seed=5) as sim:
        with pytest.raises(DeviceFault) as info:
            acquire(sim.path, plan, out)
        msg = str(info.value)
        assert f"ended {MAX_IDLE_RUNS + 1} runs in a row without a new A-line" in msg, msg
        assert "12 of 30 A-lines are on disk, re-run to resume" in msg, msg
        assert sim.stats["early_stops"] == MAX_IDLE_RUNS + 2  # the first run's end, then MAX_IDLE_RUNS + 1 idle
    assert np.array_equal(read_scan(out).completed, np.arange(30) < 12)
    again = tmp_path / "again.h5"
    with make_sim(tmp_path, faults=FaultSpec.parse(f"stop=12:{MAX_IDLE_RUNS - 1}"), seed=5) as sim:
        res = acquire(sim.path, plan, again)
        assert res.complete and res.points_done == 30
        assert sim.stats["early_stops"] == MAX_IDLE_RUNS - 1
    assert_matches_record(again, tmp_path / "truth.h5", plan)


def test_a_reset_during_the_plan_upload_is_recovered(tmp_path):
    """A device that resets on the 2nd ``PLAN:DATA`` chunk of an upload (the chunk lost with it): the
    upload starts again from ``PLAN:BEG`` (it ended with "PLAN:DATA without PLAN:BEG"), whether it is
    ``acquire``'s, before the scan file exists, or a scan's own, where the reset counts as one of the
    scan's (as a reset at A-line 5 and its recovery upload do); the scans complete bit for bit."""
    plan = grid_plan(6, 5, n_t=64)
    out = tmp_path / "scan.h5"
    with make_sim(tmp_path, faults=FaultSpec.parse("upload_reset=2"), seed=6, max_chunk=64) as sim:
        res = acquire(sim.path, plan, out)
        assert res.complete and res.points_done == 30, res
        assert sim.stats["resets"] == 1 and res.faults["upload_resets"] == 1, res.faults
    assert_matches_record(out, tmp_path / "truth.h5", plan)
    out = tmp_path / "scan-in-scan.h5"
    with make_sim(tmp_path, faults=FaultSpec.parse("reset=5,upload_reset=2:2"), seed=6, max_chunk=64) as sim:
        with Scanner(sim.path) as sc:
            with ScanFile.create(out, plan, instrument=sc.identify(), software_version="test") as sink:
                res = sc.scan(plan, sink, upload=True)
        assert res.complete and res.points_done == 30, res
        assert sim.stats["resets"] == 3
        assert res.faults["upload_resets"] == 2 and res.faults["resets"] == 3, res.faults
    assert_matches_record(out, tmp_path / "truth.h5", plan)


def test_a_reset_between_the_upload_and_the_scan_is_recovered(tmp_path):
    """The device resets after the plan was uploaded and before the scan that relies on it (``upload=False``,
    as ``acquire`` scans a new file): its ``PLAN:ID?`` answers ``NONE``, and the scan uploads the plan again,
    counting one reset (it stopped with "device holds plan NONE ...; scan with upload=True")."""
    plan = grid_plan(6, 5, n_t=64)
    out = tmp_path / "scan.h5"
    with make_sim(tmp_path, seed=8) as sim:
        with Scanner(sim.path) as sc:
            instrument = sc.identify()
            sc.upload_plan(plan)
            sim.reset()
            with ScanFile.create(out, plan, instrument=instrument, software_version="test") as sink:
                res = sc.scan(plan, sink, upload=False)
        assert res.complete and res.points_done == 30 and res.faults["resets"] == 1, res.faults
        assert sim.stats["resets"] == 1
    assert_matches_record(out, tmp_path / "truth.h5", plan)


def test_a_scanner_that_resets_on_every_upload_is_a_device_fault(tmp_path):
    plan = grid_plan(6, 5, n_t=64)
    with make_sim(tmp_path, faults=FaultSpec.parse("upload_reset=2:1000"), seed=7, max_chunk=64) as sim:
        with Scanner(sim.path, max_resets=2) as sc:
            sc.identify()
            with pytest.raises(DeviceFault, match="the scanner reset 3 times during the plan upload; the host "
                                                  "recovers from 2"):
                sc.upload_plan(plan)
        assert sim.stats["resets"] == 3


def test_max_resets_sets_the_bound(tmp_path):
    """``max_resets=0``: the first reset of a scan is already the device fault; a rerun, with
    the device no longer resetting, resumes where the file stopped."""
    plan = grid_plan(6, 5, n_t=64)
    with pytest.raises(ValueError, match="max_resets must be in 0..1000"):
        Scanner("loop://", max_resets=-1)
    out = tmp_path / "scan.h5"
    with make_sim(tmp_path, faults=FaultSpec.parse("reset=12"), seed=4) as sim:
        with pytest.raises(DeviceFault, match="the scanner reset 1 times during this scan; the host recovers "
                                              "from 0"):
            acquire(sim.path, plan, out, max_resets=0)
        done = int(read_scan(out).completed.sum())  # sent before the reset (a prefix)
        assert done <= 12 and np.array_equal(read_scan(out).completed, np.arange(30) < done)
        res = acquire(sim.path, plan, out, max_resets=0)
        assert res.complete and res.alines_received == 30 - done
    assert_matches_record(out, tmp_path / "truth.h5", plan)


def test_a_max_chunk_below_the_protocol_minimum_is_refused(tmp_path):
    """A device that takes PLAN:DATA blocks of 16 bytes at most: the host refuses it at
    ``identify`` with a ``DeviceFault`` naming both numbers (it would otherwise retry a chunk
    at 64 bytes, which the device refuses); ``acquire`` uploads nothing and leaves no file."""
    plan = grid_plan(5, 5, n_t=64)
    out = tmp_path / "scan.h5"
    with make_sim(tmp_path, max_chunk=16) as sim, Scanner(sim.path) as sc:
        with pytest.raises(DeviceFault, match=f"max_chunk is 16 bytes, below the protocol's minimum of {MIN_CHUNK}"):
            sc.identify()
        with pytest.raises(DeviceFault, match="max_chunk is 16 bytes"):
            acquire(sim.path, plan, out, scanner=sc)
        assert sc.query("PLAN:ID?") == "NONE"
        assert not out.exists()


def test_a_max_chunk_of_64_takes_every_chunk_on_a_noisy_link(tmp_path):
    """The protocol's minimum: chunks of at most 64 bytes, retried no smaller, on a link that
    corrupts bytes (so chunks are retried): the plan reaches the device, which holds its id
    (a chunk the device refused would end the upload with error -223)."""
    plan = grid_plan(20, 20, n_t=64)  # a 1.7 kB plan image: 27 chunks
    with make_sim(tmp_path, max_chunk=MIN_CHUNK, faults=FaultSpec.parse("corrupt=5e-3"), seed=5) as sim:
        with Scanner(sim.path) as sc:
            assert sc.identify()["limits"]["max_chunk"] == MIN_CHUNK
            assert sc.upload_plan(plan) == plan["id"]
            assert sc.faults["upload_retries"] > 0, sc.faults
            assert sc.query("PLAN:ID?") == plan["id"]


@pytest.mark.waits  # the no-progress bound is a real 3 s
def test_a_scanner_that_ignores_acks_ends_in_bounded_time(tmp_path):
    """From A-line 40 on the device ignores ACKs: it fills its window with new A-lines, then
    resends its oldest unacknowledged one every RTO (20 ms here), for ever. The host, never
    silent for its stall poll (0.3 s), still ends the scan once no new A-line came for its
    no-progress bound (``max(3·response_timeout, 10·stall silence)``, 3 s) with ``DeviceTimeout``; the
    device is left idle, the file holds every A-line received, a rerun completes it."""
    plan = grid_plan(20, 20, n_t=64)
    n = 400
    out = tmp_path / "scan.h5"
    with make_sim(tmp_path, faults=FaultSpec.parse("ignore_acks=40"), seed=6, rto=0.02) as sim:
        with Scanner(sim.path, response_timeout=1.0, stall_timeout=0.3) as sc:
            sink = ScanFile.create(out, plan, instrument=sc.identify(), software_version="test")
            with sink:
                with pytest.raises(DeviceTimeout, match="reports RUNNING but delivered no new A-line"):
                    sc.scan(plan, sink)
                done = int(sink.completed().sum())
            assert sim.state == "IDLE" and sim.stats["timeouts"] > 0  # it did resend, for a while
            assert 40 <= done < n and np.array_equal(read_scan(out).completed, np.arange(n) < done)
            res = acquire(sim.path, plan, out, scanner=sc)
            assert res.complete
    assert_matches_record(out, tmp_path / "truth.h5", plan)


FLOOD = 256 * MB  #: bytes the flooding device sends while the host is not reading

FLOOD_HOST = r"""
import json, sys
from fpscan.driver.host import DriverError, Scanner
from tests.rss import resident

with Scanner(sys.argv[1], reader="thread") as sc:
    print("BASE", resident(), flush=True)
    sys.stdin.readline()  # the device floods the port meanwhile; nobody reads it here
    try:
        sc.query("*IDN?", timeout=2.0)
        outcome = {"error": None}
    except DriverError as exc:
        outcome = {"error": type(exc).__name__, "message": str(exc)}
    outcome["after"] = resident()
print("RESULT", json.dumps(outcome), flush=True)
"""


def test_a_flood_on_the_thread_reader_ends_as_a_lost_device_in_bounded_memory(tmp_path):
    """256 MiB of bytes without a frame delimiter sent to a host (``reader="thread"``) that is
    not reading: its resident size stays within 50 MB of what it was (the reader holds at most
    ``THREAD_QUEUE_BYTES``, 32 MiB, and discards the rest), and its next command ends with a
    ``DriverError`` that says the device flooded it. The device is this test on a raw pty."""
    assert THREAD_QUEUE_BYTES + 8 * MB < GROWTH
    master, slave = pty.openpty()
    tty.setraw(slave)
    proc = subprocess.Popen([sys.executable, "-c", FLOOD_HOST, os.ttyname(slave)], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True)  # type: ignore[union-attr]
    reader.start()
    written = threading.Event()
    sent = [0]

    def flood() -> None:
        block = bytes(range(1, 256)) * 4096  # ~1 MiB, no 0x00: no frame ever ends
        try:
            while sent[0] < FLOOD:
                sent[0] += os.write(master, block[:FLOOD - sent[0]])
        except OSError:  # the host was killed (over its memory bound): the check below says so
            pass
        written.set()

    watch = None
    try:
        deadline = time.monotonic() + HANG_S
        first = ""
        while not first:
            try:
                first = lines.get(timeout=0.05)
            except queue.Empty:
                assert proc.poll() is None, proc.stderr.read()[-3000:]  # type: ignore[union-attr]
                assert time.monotonic() < deadline, "the host did not start"
        assert first.startswith("BASE"), first
        watch = RssWatch(proc.pid, base=int(first.split()[1]), limit=GROWTH, what="the host").start()
        threading.Thread(target=flood, daemon=True).start()
        go = False
        while proc.poll() is None:
            if written.is_set() and not go:
                assert sent[0] == FLOOD
                proc.stdin.write("go\n")  # type: ignore[union-attr]
                proc.stdin.flush()  # type: ignore[union-attr]
                go = True
            assert time.monotonic() < deadline, "the host did not stop"
            try:
                proc.wait(timeout=0.02)
            except subprocess.TimeoutExpired:
                pass
        watch.stop()
        watch.check(f"while the device flooded it ({sent[0] / MB:.0f} MB sent)")
        reader.join(timeout=HANG_S)
        out = []
        while not lines.empty():
            out.append(lines.get())
        result = [line for line in out if line.startswith("RESULT")]
        assert proc.returncode == 0 and result, (proc.returncode, out, proc.stderr.read()[-3000:])  # type: ignore[union-attr]
        report = json.loads(result[-1].split(" ", 1)[1])
        print(f"host RSS: {watch.base / MB:.1f} MB before the flood, peak {watch.peak / MB:.1f} MB, "
              f"{report['after'] / MB:.1f} MB after it")
        assert report["error"] == "DriverError", report
        assert "(a flood)" in report["message"] and "bytes were discarded" in report["message"], report
        assert report["after"] - watch.base < GROWTH
    finally:
        if watch is not None:
            watch.stop()
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=HANG_S)
        for fd in (master, slave):
            os.close(fd)
