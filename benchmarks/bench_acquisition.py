"""Acquisition throughput over a real pty.

Measures, in one run:
1. the raw pty byte rate: a thread writes 1 MiB blocks into the master side as fast as it
   can, the host reads the slave side through pyserial (same read path as the driver);
2. the unthrottled simulated scanner (PRF 0, A-lines precomputed at plan upload so the
   timed window holds only the link) streaming a plan of >= 20 000 points with 2048
   int16 samples into a scan file via the host driver: A-lines/s landed in the file.
Prints both and their ratio: A-lines/s × wire bytes per A-line ÷ raw pty bytes/s.
Targets: >= 5000 A-lines/s and >= 40 %.

    .venv/bin/python benchmarks/bench_acquisition.py [--side 142] [--n-t 2048]
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import pty
import select
import signal
import sys
import tempfile
import time
import tty
from pathlib import Path

from fpscan.driver.aline import ALINE_HEADER
from fpscan.driver.framing import HEADER, FrameType, encode_frame
from fpscan.driver.plan import plan_id_of
from fpscan.physics.axes import centred_positions


def raw_pty_rate(seconds: float = 2.0) -> float:
    """Bytes/s through a raw pty: a writer process on the master side, the host reading
    the slave side (opened with pyserial, read as the driver reads it: select + os.read)."""
    import serial

    master, slave = pty.openpty()
    tty.setraw(slave)
    ser = serial.Serial(os.ttyname(slave), timeout=0.02)
    block = os.urandom(1 << 20)

    def writer():
        view = memoryview(block)
        while True:
            off = 0
            while off < len(view):
                off += os.write(master, view[off:])

    pid = os.fork()
    if pid == 0:  # the writer runs in its own process, like the simulated scanner
        try:
            writer()
        finally:
            os._exit(0)
    got = 0
    t0 = time.perf_counter()
    while (t := time.perf_counter()) - t0 < seconds:
        if select.select([ser.fd], [], [], 0.02)[0]:
            got += len(os.read(ser.fd, 1 << 18))
    rate = got / (t - t0)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    ser.close()
    os.close(master)
    os.close(slave)
    return rate


def _run_sim(cfg, conn) -> None:
    from fpscan.driver.simulator import SimulatedScanner

    with SimulatedScanner(cfg) as sim:
        conn.send(sim.path)
        conn.recv()


def grid_plan(side: int, n_t: int, dt: float = 8e-9, pitch: float = 6e-5) -> dict:
    idx = [[ix if iy % 2 == 0 else side - 1 - ix, iy] for iy in range(side) for ix in range(side)]
    pos = [[float(centred_positions(ix, side, pitch)), float(centred_positions(iy, side, pitch))] for ix, iy in idx]
    plan = {"format": "fpscan-plan/1", "lattice": {"n_x": side, "n_y": side, "pitch": pitch},
            "mask": {"kind": "grid", "params": {}, "requested_points": len(idx),
                     "obtained_points": len(idx), "weight_ratio": 1.0},
            "points": {"indices": idx, "positions": pos, "weights": [pitch * pitch] * len(idx)},
            "order": "serpentine",
            "acquisition": {"n_t": n_t, "dt": dt, "averages": 1, "wavelengths": [7.5e-7],
                            "prf": 0.0, "sound_speed": 1500.0}}
    plan["id"] = plan_id_of(plan)
    return plan


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--side", type=int, default=142, help="lattice side (142 -> 20164 points)")
    ap.add_argument("--n-t", type=int, default=2048)
    ap.add_argument("--window", type=int, default=256)
    ap.add_argument("--readers", nargs="+", default=["process", "thread"],
                    choices=["process", "thread", "direct"],
                    help="host reader modes to measure (the first is the headline figure)")
    args = ap.parse_args()

    import psutil

    from fpscan.driver.host import Scanner
    from fpscan.driver.scanfile import ScanFile, read_scan
    from fpscan.driver.simulator import SimConfig
    from fpscan.driver.sources import BallSource
    from fpscan.physics import Ball

    plan = grid_plan(args.side, args.n_t)
    n = len(plan["points"]["indices"])
    wire = len(encode_frame(FrameType.ALINE, bytes(ALINE_HEADER.size + 2 * args.n_t)))
    print(f"plan: {n} points x {args.n_t} int16 samples; ~{wire} wire bytes per A-line "
          f"(frame header {HEADER.size} + A-line header {ALINE_HEADER.size} + samples + CRC "
          f"+ COBS)")

    raw = raw_pty_rate()
    print(f"raw pty byte rate (pyserial reader): {raw / 1e6:.1f} MB/s "
          f"= {raw / wire:.0f} A-line frames/s")

    balls = [Ball(0.0, 0.0, 3.0e-3, 0.2e-3, 1.0), Ball(1e-3, -1e-3, 5.0e-3, 0.3e-3, 0.8)]
    cfg = SimConfig(source=BallSource(balls), prf=0.0, precompute=True, max_window=args.window)
    # the simulated scanner runs in its own process, as a real scanner is its own device
    ctx = multiprocessing.get_context("fork")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_run_sim, args=(cfg, child), daemon=True)
    proc.start()
    path = parent.recv()
    results = {}
    with tempfile.TemporaryDirectory() as d:
        # warm-up (not reported): first use of the file system, HDF5 and the code paths
        warm = grid_plan(24, args.n_t)
        with Scanner(path, window=args.window, response_timeout=300) as sc:
            sc.identify()
            sc.upload_plan(warm)
            with ScanFile.create(Path(d) / "warm.h5", warm, instrument={},
                                 software_version="bench") as sf:
                sc.scan(warm, sf, upload=False)
        for reader in args.readers:
            out = Path(d) / f"scan-{reader}.h5"
            with Scanner(path, window=args.window, response_timeout=300, reader=reader) as sc:
                sc.identify()
                t = time.perf_counter()
                sc.upload_plan(plan)  # the simulator precomputes every A-line here
                print(f"[{reader} reader] plan upload + A-line precomputation: "
                      f"{time.perf_counter() - t:.1f} s")
                procs = {"simulator": psutil.Process(proc.pid), "host": psutil.Process()}
                relay = getattr(sc._reader, "process", None)  # fpscan.driver.transport.RelayReader
                if relay is not None:
                    procs["relay"] = psutil.Process(relay.pid)
                cpu0 = {k: sum(p.cpu_times()[:2]) for k, p in procs.items()}
                with ScanFile.create(out, plan, instrument={}, software_version="bench") as sf:
                    res = sc.scan(plan, sf, upload=False)
                cpu = {k: sum(p.cpu_times()[:2]) - cpu0[k] for k, p in procs.items()}
            scan = read_scan(out)
            assert scan.completed.all() and res.complete
            rate = n / res.acquisition_s
            results[reader] = rate
            print(f"[{reader} reader] {n} A-lines in {res.acquisition_s:.2f} s = {rate:.0f} "
                  f"A-lines/s ({rate * wire / 1e6:.1f} MB/s) into the scan file; "
                  f"{100 * rate * wire / raw:.0f} % of the raw pty byte rate; faults {res.faults}, "
                  f"link {res.link}")
            print(f"[{reader} reader] CPU use during the scan (1.0 = one core): " + ", ".join(
                f"{k} {v / res.elapsed_s:.2f}" for k, v in cpu.items()))
    parent.send("stop")
    proc.join(timeout=30)
    rate = results[args.readers[0]]
    frac = rate * wire / raw
    print(f"result ({args.readers[0]} reader): {rate:.0f} A-lines/s, {100 * frac:.0f} % of the "
          f"raw pty byte rate; targets: >= 5000 A-lines/s: "
          f"{'met' if rate >= 5000 else 'NOT met'}; >= 40 %: {'met' if frac >= 0.4 else 'NOT met'}")
    print(f"load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
