"""A scanner whose word no plan allows: one A-line frame with a good CRC, run id and boot id
but a data sequence number far outside its run (2³¹ ahead, or 0xFFFFFFFF), a point the plan
does not have, or a field out of its documented range (docs/protocol.md §5: a ``dc_level`` of 0
or −1, a NaN or infinite ``scale``, a ``dt`` of 0, a sample of −32 768), is a device fault.
The scan stops with the reason (``DeviceFault``), the device is left idle, the scan file holds
every A-line the device sent before, and a rerun completes the scan bit for bit; the host's
memory stays within 50 MB of what it was before the scan (its bookkeeping is the plan's size,
never the size the device claims).

The host runs in a child process (the simulated scanner, on a real pty, in this one): it reports
its own resident size (``/proc/self/status``) before the scan and after the fault, and this
process watches the child's peak resident size meanwhile (``tests.rss.RssWatch``) and ends the
child once it is 50 MB over,
so a host that builds a list of every "missing" sequence number fails the test instead of
taking the machine's memory.
"""
from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from fpscan.driver.acquire import acquire
from fpscan.driver.faults import FaultSpec
from fpscan.driver.scanfile import read_scan
from fpscan.driver.simulator import SimConfig, SimulatedScanner
from fpscan.driver.sources import BallSource
from tests.driver.driver_helpers import grid_plan, small_phantom
from tests.driver.test_link import assert_matches_record
from tests.rss import MB, ROOT, RssWatch
from tests.waits import HANG_S

pytestmark = [pytest.mark.timeout(300)]

GROWTH = 50 * MB  #: the most the host's resident size may grow
K = 40  #: the A-line before which the device's data sequence skips

HOST = r"""
import json, sys
from fpscan.driver.host import DriverError, Scanner
from fpscan.driver.plan import load_plan
from fpscan.driver.scanfile import ScanFile
from tests.rss import resident

port, plan_path, out = sys.argv[1:4]
plan = load_plan(plan_path)
with Scanner(port) as sc:
    sink = ScanFile.create(out, plan, instrument=sc.identify(), software_version="test")
    print("BASE", resident(), flush=True)
    try:
        res = sc.scan(plan, sink)
        outcome = {"error": None, "complete": res.complete}
    except DriverError as exc:
        outcome = {"error": type(exc).__name__, "message": str(exc)}
    finally:
        sink.close()
    outcome["after"] = resident()
print("RESULT", json.dumps(outcome), flush=True)
"""


def run_host(port: str, plan_path, out) -> dict:
    """Scan in a child process (``HOST``); its report, with ``base`` and ``peak`` resident sizes.
    Fails (and ends the child) once the child's resident size is ``GROWTH`` over its base."""
    proc = subprocess.Popen([sys.executable, "-c", HOST, port, str(plan_path), str(out)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()

    def read() -> None:
        for line in proc.stdout:  # type: ignore[union-attr]
            lines.put(line)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    watch = None
    try:
        deadline = time.monotonic() + HANG_S
        first = ""
        while not first:  # its resident size before the scan, or its exit
            try:
                first = lines.get(timeout=0.05)
            except queue.Empty:
                assert proc.poll() is None, proc.stderr.read()[-3000:]  # type: ignore[union-attr]
                assert time.monotonic() < deadline, "the host did not start"
        assert first.startswith("BASE"), first
        watch = RssWatch(proc.pid, base=int(first.split()[1]), limit=GROWTH, what="the host").start()
        try:
            proc.wait(timeout=max(deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            pytest.fail("the host did not stop")
        watch.stop()
        watch.check("after the device fault")
        reader.join(timeout=HANG_S)
        out_lines = []
        while not lines.empty():
            out_lines.append(lines.get())
        result = [l for l in out_lines if l.startswith("RESULT")]
        assert proc.returncode == 0 and result, (proc.returncode, out_lines, proc.stderr.read()[-3000:])  # type: ignore[union-attr]
        report = json.loads(result[-1].split(" ", 1)[1])
        report.update(base=watch.base, peak=watch.peak)
        return report
    finally:
        if watch is not None:
            watch.stop()
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=HANG_S)


# the plan below has 400 A-lines; the first run numbers them 0 … 399
CASES = {
    "seq 2^31 ahead": (f"seq={K}:{2**31 + K}", f"sequence number {2**31 + K} is outside run 1"),
    "seq 0xFFFFFFFF": (f"seq={K}:{0xFFFFFFFF}", "sequence number 4294967295 is outside run 1"),
    "point 2^32-1": (f"point={K}:{2**32 - 1}", "of point 4294967295, wavelength 0 with 128 samples; the plan has 400 "
                                                "points"),
    # a field out of its documented range (docs/protocol.md §5): the scan file would refuse the A-line
    "dc_level 0": (f"field={K}:dc_level:0", f"A-line (seq {K}) of point {K}, wavelength 0: dc_level = 0.0 V is out "
                                            "of its range (finite and > 0)"),
    "dc_level -1": (f"field={K}:dc_level:-1", "dc_level = -1.0 V is out of its range"),
    "scale nan": (f"field={K}:scale:nan", "scale = nan signal per count is out of its range (finite and > 0)"),
    "scale inf": (f"field={K}:scale:inf", "scale = inf signal per count is out of its range"),
    "dt 0": (f"field={K}:dt:0", "dt = 0.0 s is out of its range (finite and > 0)"),
    "sample -32768": (f"field={K}:sample:-32768", "a sample of -32768 is out of the range -32767 … 32767"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_number_no_plan_allows_is_a_device_fault_in_bounded_memory(tmp_path, case):
    spec, says = CASES[case]
    plan = grid_plan(20, 20, n_t=128)
    n = len(plan["points"]["indices"])
    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps(plan))
    out = tmp_path / "scan.h5"
    faults = FaultSpec.parse(spec)
    with SimulatedScanner(SimConfig(source=BallSource(small_phantom()), prf=0.0, seed=7, faults=faults,
                                    record=tmp_path / "truth.h5")) as sim:
        report = run_host(sim.path, plan_path, out)
        print(f"host RSS: {report['base'] / MB:.1f} MB before the scan, peak {report['peak'] / MB:.1f} MB, "
              f"{report['after'] / MB:.1f} MB after the fault ({case})")
        assert report["error"] == "DeviceFault", report
        assert report["message"].startswith("device fault: ") and says in report["message"], report
        assert f"{K} of {n} A-lines are on disk" in report["message"], report
        assert report["after"] - report["base"] < GROWTH and report["peak"] - report["base"] < GROWTH
        assert sim.state == "IDLE"  # the host stopped the run it started
        # every A-line the device sent before the fault, and none after
        assert np.array_equal(read_scan(out).completed, np.arange(n) < K)
        res = acquire(sim.path, plan, out)  # the rerun resumes the file and completes it
        assert res.complete and res.points_done == n
    assert_matches_record(out, tmp_path / "truth.h5", plan)
