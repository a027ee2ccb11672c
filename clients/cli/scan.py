"""`fpscan scan`: acquire a plan from a scanner straight into a scan file.

Resumes when ``--out`` already holds a partial scan of the same plan (only the missing
points are acquired). Exit codes: 0 complete, 1 error or incomplete, 130 interrupted (the
scanner is left idle and the file keeps every point acquired so far).
"""
from __future__ import annotations

COMMAND = "scan"
HELP = "acquire a plan from the scanner (or simulator) into a scan file, resuming a partial one"


def add_arguments(parser):
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser)."""
    parser.add_argument("--device", required=True,
                        help="serial device path (/dev/ttyACM0, /dev/pts/N) or pyserial URL")
    parser.add_argument("--plan", required=True, help="plan JSON written by `fpscan plan`")
    parser.add_argument("--out", required=True, help="scan file (HDF5); resumed if it exists")
    parser.add_argument("--window", type=int, default=256, help="credit window in A-lines (the device caps it at its limit)")
    parser.add_argument("--timeout", type=float, default=10.0,
                        help="longest wait for a silent device, s (default 10)")
    parser.add_argument("--fsync", action="store_true",
                        help="fsync the scan file after every A-line (survives power loss)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def run(args) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status."""
    import sys

    from clients.cli._common import ProgressBar
    from driver.acquire import acquire

    if args.window < 1 or args.timeout <= 0:
        raise ValueError("--window must be >= 1 and --timeout > 0")
    with ProgressBar("scan", quiet=args.quiet) as bar:
        def progress(p):
            bar({"stage": p.state, "points_done": p.points_done, "points_total": p.n_points,
                 "rate_per_s": p.rate,
                 "eta_s": p.eta_s if p.eta_s < float("inf") else None,
                 "faults_recovered": p.faults_recovered})

        result = acquire(args.device, args.plan, args.out, progress=progress,
                         durable="fsync" if args.fsync else "process", window=args.window,
                         response_timeout=args.timeout)
    rate = (result.points_done / result.elapsed_s) if result.elapsed_s > 0 else 0.0
    n_faults = result.faults_recovered
    print(f"{args.out}: {result.points_done}/{result.n_points} points complete in "
          f"{result.elapsed_s:.1f} s ({rate:.0f} points/s), {n_faults} link faults recovered")
    if not result.complete:
        print(f"fpscan scan: error: scan incomplete ({'aborted' if result.aborted else 'stopped'})"
              "; run the same command again to resume", file=sys.stderr)
        return 1
    return 0
