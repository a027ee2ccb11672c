"""`fpscan scan`: acquire a plan from a scanner straight into a scan file, or run the
scan as a job on a server.

Locally (``--device``): resumes when ``--out`` already holds a partial scan of the same
plan (only the missing points are acquired). With ``--server URL --scanner ID``: the plan
(a plan JSON file, uploaded under its own id, or the id of a plan on the server) is
scanned as a server job (``POST /api/scans``) with a progress bar; ``--out`` then gets the
scan file when it is done; ``--preview-wavelength M`` picks which of a multi-wavelength
plan's excitation wavelengths the server's live preview shows. Exit codes: 0 complete,
1 error or incomplete, 130 interrupted by Ctrl-C (SIGINT), 143 stopped by SIGTERM (``kill``):
either way the scanner is left idle, the file is closed cleanly (any HDF5 reader opens it,
``h5py.File(path, "r")`` included) and keeps every point acquired so far, and the message
says how many points it holds and to run the same command again to resume; a second
signal while it stops is ignored. After ``kill -9`` or a power cut the file is left open
for writing: the same command resumes it, ``fpscan repair`` closes it. Rates count only
the points this run acquired.
"""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import UsageError, add_server_options, client_errors, seconds

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    import os
    from pathlib import Path
    from typing import Any

    from fpscan.driver.host import ScanProgress

__all__ = ["COMMAND", "HELP", "add_arguments", "preview_index", "run"]

COMMAND = "scan"
HELP = "acquire a plan from the scanner (or simulator) into a scan file, resuming a partial one"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare ``fpscan scan``'s options on ``parser`` (local device or server job).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    parser.add_argument("--device",
                        help="serial device path (/dev/ttyACM0, /dev/pts/N) or pyserial URL (local scan)")
    parser.add_argument("--plan", required=True,
                        help="plan JSON written by `fpscan plan` (with --server: or a plan id on the server)")
    parser.add_argument("--out", help="scan file (HDF5); resumed if it exists (local: required; "
                                      "with --server: where to download the finished scan)")
    g = parser.add_argument_group("server (instead of --device)")
    add_server_options(g)
    g.add_argument("--scanner", metavar="ID", help="with --server: the server's scanner id "
                   "(default: its only scanner)")
    g.add_argument("--preview-wavelength", metavar="M", type=_wavelength_arg,
                   help="with --server: the excitation wavelength in m (one of the plan's) that the "
                        "live preview shows (default: the plan's first)")
    parser.add_argument("--window", type=int, default=256, help="credit window in A-lines (the device caps it at its limit)")
    parser.add_argument("--timeout", type=seconds("--timeout"), default=10.0,
                        help="longest wait for a silent device, s (default 10)")
    parser.add_argument("--fsync", action="store_true",
                        help="fsync the scan file after every A-line (survives power loss)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _points_on_disk(path: str | os.PathLike) -> int:
    """Completed points already in the scan file ``path`` (0 if there is none yet)."""
    from fpscan.driver.scanfile import completed_count

    try:
        return completed_count(path)
    except (OSError, ValueError):
        return 0  # none yet, or not a scan file: acquire() says so


def _same_command() -> str:
    import shlex
    import sys

    return "fpscan " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def _wavelength_arg(text: str) -> float:
    from fpscan.clients.cli.plan import parse_value

    return parse_value(text, "m")


def preview_index(wavelengths: list, wanted: float) -> int:
    """Index of ``wanted`` (m) among a plan's excitation ``wavelengths`` (m; equal to
    1e-6 relative); ``ValueError`` naming the plan's wavelengths when it is not one.

    Parameters
    ----------
    wavelengths : list of float
        The plan's excitation wavelengths, m.
    wanted : float
        The wavelength asked for, m.

    Returns
    -------
    int
        Its index in ``wavelengths``.

    Raises
    ------
    UsageError
        ``wanted`` is none of them (a ``ValueError``).
    """
    for k, w in enumerate(wavelengths):
        if abs(float(w) - wanted) <= 1e-6 * abs(float(w)):
            return k
    have = ", ".join(f"{float(w):g}" for w in wavelengths)
    raise UsageError(f"--preview-wavelength {wanted:g} m is not one of the plan's wavelengths ({have} m)")


@client_errors
def run(args: argparse.Namespace) -> int:
    """Acquire locally (``--device``) or as a server job (``--server``); exit status.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        The exit status of a local scan: 0 when the scan is complete; 1 incomplete (aborted or
        stopped); 2 a ``--plan`` that is no plan; 130 interrupted (SIGINT), 143 stopped by SIGTERM
        (the file closed; the same command resumes).
        Errors of the client become exit 1, or 2 when the server refused the request as given
        (``fpscan.clients.cli.common.client_errors``).
    """
    import signal
    import sys
    import time

    from fpscan.clients.cli.common import ProgressBar

    if args.server and not args.device:  # --device wins over $FPSCAN_SERVER
        return _remote(args)
    if not args.device or not args.out:
        raise UsageError("a local scan needs --device and --out (or use --server URL)")
    if args.preview_wavelength is not None:
        raise UsageError("--preview-wavelength is for a scan on a server (--server): a local scan has no live preview")
    from fpscan.driver.acquire import acquire
    from fpscan.service.formats.plan import read_plan

    if args.window < 1:
        raise UsageError("--window must be >= 1")
    try:
        plan = read_plan(args.plan)  # a wrong file is named before the device is opened
    except ValueError as exc:
        return _bad_plan(exc)
    before = _points_on_disk(args.out)
    last: dict = {}
    t0 = time.monotonic()
    stop = _StopOnSignal()
    try:
        with stop, ProgressBar("scan", quiet=args.quiet) as bar:
            def progress(p: ScanProgress) -> None:
                last.update(done=p.points_done, total=p.n_points)
                bar({"stage": p.state, "points_done": p.points_done, "points_total": p.n_points,
                     "rate_per_s": p.rate,
                     "eta_s": p.eta_s if p.eta_s < float("inf") else None,
                     "faults_recovered": p.faults_recovered})

            result = acquire(args.device, plan, args.out, progress=progress,
                             durable="fsync" if args.fsync else "process", window=args.window,
                             response_timeout=args.timeout)
    except KeyboardInterrupt as exc:
        # the scan file is closed (acquire's sink.close(), which no signal interrupts): count
        # what it holds now, not what a progress report said before
        signum = exc.signum if isinstance(exc, _Stopped) else signal.SIGINT
        done = _points_on_disk(args.out)
        this_run, seconds = max(done - before, 0), time.monotonic() - t0
        total = f"/{last['total']}" if "total" in last else ""
        how = "" if signum == signal.SIGINT else f" ({signal.Signals(signum).name})"
        print(f"fpscan scan: interrupted{how}: {done}{total} points are in {args.out} ({this_run} this run in "
              f"{seconds:.1f} s). The scanner is idle; to resume, run the same command again:\n"
              f"  {_same_command()}", file=sys.stderr)
        return 128 + signum
    this_run = max(result.points_done - before, 0)
    rate = this_run / result.acquisition_s if result.acquisition_s > 0 else 0.0
    n_faults = result.faults_recovered
    spectral = (f" ({result.alines_done}/{result.n_alines} A-lines at "
                f"{result.n_alines // max(result.n_points, 1)} wavelengths)"
                if result.n_alines > result.n_points else "")
    resumed = f" ({before} from before, resumed)" if before else ""
    print(f"{args.out}: {result.points_done}/{result.n_points} points complete{spectral}{resumed}; this run "
          f"{this_run} points in {result.acquisition_s:.1f} s of acquisition ({rate:.0f} points/s), "
          f"{n_faults} link faults recovered")
    if not result.complete:
        print(f"fpscan scan: error: scan incomplete ({'aborted' if result.aborted else 'stopped'})"
              "; run the same command again to resume", file=sys.stderr)
        return 1
    return 0


class _Stopped(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped a local scan (``signum``): raised in the main thread like
    Ctrl-C's ``KeyboardInterrupt``, so the scan leaves the device idle and closes its file."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


class _StopOnSignal:
    """While a local scan runs: SIGINT and SIGTERM raise :class:`_Stopped` once; a second
    signal, while the scan stops (the device left idle, the file closed), is ignored, so
    that nothing breaks off the file's close (``kill -9`` still ends the process)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._before: dict[int, Any] = {}

    def _on_signal(self, signum: int, frame: object) -> None:
        if self.signum is None:
            self.signum = signum
            raise _Stopped(signum)

    def __enter__(self) -> _StopOnSignal:
        import signal

        for signum in (signal.SIGINT, signal.SIGTERM):
            self._before[signum] = signal.signal(signum, self._on_signal)
        return self

    def __exit__(self, *exc: object) -> None:
        import signal

        for signum, handler in self._before.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


def _bad_plan(exc: ValueError) -> int:
    """A ``--plan`` that is no plan (another kind of file, not JSON, a plan that fails its
    check) is a usage error: its reason on one line, exit 2."""
    import sys

    print(f"fpscan scan: error: {exc}", file=sys.stderr)
    return 2


def _plan_json(source: Path) -> dict:
    """The JSON of the plan file ``source`` (a plan, or a plan request the server builds),
    as the server is sent it. Raises ValueError: a file that is not JSON text is named by
    registry of formats (``fpscan.service.formats.plan.read_plan``: "this is a scan file, not a
    plan"), bad JSON with its position."""
    import json

    raw = source.read_bytes()
    try:
        return json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        from fpscan.service.formats.plan import read_plan

        read_plan(source)  # raises, naming the kind of file (scan, result, IPASC, NumPy, PNG)
        raise ValueError(f"{source}: not a plan: the file is not UTF-8 JSON text") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{source} is not valid JSON: {exc}") from None


def _remote(args: argparse.Namespace) -> int:
    """The scan as a server job: upload the plan JSON (or take a plan id), start the scan,
    follow it with a progress bar, download the scan file to ``--out``."""
    from pathlib import Path

    from fpscan.clients.cli.common import ProgressBar, make_client
    from fpscan.clients.http import field_of

    source = Path(args.plan)
    try:
        plan = _plan_json(source) if source.is_file() else None  # a wrong file is named before any request
    except ValueError as exc:
        return _bad_plan(exc)
    with make_client(args) as api:
        if plan is not None:
            created = api.create_plan(plan)
            plan_id = field_of(created, "id")
            if isinstance(plan, dict) and plan.get("id") not in (None, plan_id):
                raise RuntimeError(f"the server stored {source} as {plan_id}, not {plan.get('id')}")
        else:
            created = api.get_plan(args.plan)
            plan_id = field_of(created, "id")
        extra: dict[str, Any] = {}
        if args.preview_wavelength is not None:
            wavelengths = (field_of(created, "acquisition") or {}).get("wavelengths") or []
            extra["preview_wavelength"] = preview_index(wavelengths, args.preview_wavelength)
        scanner = args.scanner
        if scanner is None:
            ids = [field_of(s, "id") for s in api.scanners()]
            if len(ids) != 1:
                raise UsageError(f"the server has scanners {', '.join(ids) or '(none)'}: choose one with --scanner")
            scanner = ids[0]
        job_id = api.start_scan(plan_id, scanner, **extra)
        if job_id is None:  # a 202 names its job (fpscan.clients.http.calls.read_job_id): this one did not
            raise RuntimeError(f"the server accepted the job (HTTP 202) but named no job id; find it with "
                               f"`fpscan jobs list --server {args.server}`")
        from fpscan.clients.cli.common import remember_job

        remember_job(args, job_id)
        with ProgressBar(f"scan {job_id[:8]}", quiet=args.quiet) as bar:
            job = api.wait(job_id, on_progress=bar)
        progress = field_of(job, "progress")
        if args.out:
            api.download_scan(job_id, args.out)
    done = field_of(progress, "points_done") if progress is not None else None
    total = field_of(progress, "points_total") if progress is not None else None
    print(f"scan job {job_id} on {args.server}: plan {plan_id[:12]}, scanner {scanner}, "
          f"{done}/{total} points" + (f"; wrote {args.out}" if args.out else ""))
    return 0
