"""Helpers shared by the CLI subcommands (one module each in :mod:`fpscan.clients.cli`):
server URL/token options and the client, input and output checks, flags with units,
progress bars for scans (points/s, ETA) and reconstructions (stages), and one-line errors
(:class:`UsageError`: exit 2; :func:`client_errors`: the client's errors as exit 1 or 2)."""
from __future__ import annotations

import argparse
import functools
import os
import sys
import time

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Mapping, Sequence
    from typing import Any, TextIO

    from rich.progress import Progress, TaskID

    from fpscan.clients.http import Client

try:  # the base of refused input (a unit mistake, an option outside its rule): exit 2
    from fpscan.driver.units import RefusedInput
except ImportError:  # pragma: no cover -- fpscan.driver.units is part of every install
    RefusedInput = ValueError  # type: ignore[misc,assignment]

__all__ = ["UsageError", "wrong_file", "check_input_files", "sniff_format", "add_server_options", "default_dtype",
           "EXTRA_OF_MODULE", "missing_extra", "needs_extra", "speed", "add_progress_option", "make_client",
           "TOKEN_HINT", "client_errors", "remember_job", "unreachable_hint", "describe_progress", "PROGRESS_PERIOD_S",
           "progress_period", "ProgressBar", "quantity", "seconds", "seed", "format_bytes", "check_out_writable", "full_job_id",
           "delete_each"]


class UsageError(RefusedInput):
    """The command line itself is refused before any work: a flag missing or combined with
    one it excludes, a value out of range, a named file that does not exist. ``fpscan``
    prints it on one line and exits 2, like argparse's own usage errors.

    A :class:`fpscan.driver.units.RefusedInput` (a ``ValueError``): :func:`fpscan.clients.cli.main`
    reports every refused input alike.

    Parameters
    ----------
    message : str
        The reason, in the command line's terms (the flags by name).
    """


def wrong_file(path: str | os.PathLike, wanted: str) -> str | None:
    """Name what a file given as ``wanted`` is when it is a file of another format.

    The format is named by the registry of formats (``fpscan.service.formats.describe``: the
    one format sniffer).

    Parameters
    ----------
    path : str or os.PathLike
        The file given (anything else gives None).
    wanted : str
        What the command wanted, as a noun (``"a plan"``).

    Returns
    -------
    str or None
        ``"<path>: this is a scan file, not <wanted>"``; None when it is a plan (``"plan"``),
        of no known format or not a file (the caller's own reason stands).
    """
    from pathlib import Path

    if not isinstance(path, (str, os.PathLike)) or not Path(path).is_file():
        return None
    from fpscan.service.formats import describe

    what = describe(path, unless=("plan",))
    return f"{path}: this is {what}, not {wanted}" if what else None


def check_input_files(args: argparse.Namespace, paths: list[str], missing: str) -> None:
    """Refuse a local-input or ``--scan-job`` choice that cannot run (``fpscan recon``, ``fpscan unmix``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line; reads ``scan_job`` and ``server``.
    paths : list of str
        The INPUT files given (empty when none).
    missing : str
        What to give, for the "no input" reason.

    Raises
    ------
    UsageError
        (exit 2, one line) ``--scan-job`` without ``--server``; both INPUT and ``--scan-job``;
        neither; an INPUT that is no file.
    """
    from pathlib import Path

    if args.scan_job and not args.server:
        raise UsageError("--scan-job needs --server")
    if args.scan_job and paths:
        raise UsageError("give either INPUT or --scan-job, not both")
    if args.scan_job:
        return
    if not paths:
        raise UsageError(f"no input: {missing}")
    for p in paths:
        if not Path(p).is_file():
            raise UsageError(f"no such file: {p}")


def sniff_format(path: str | os.PathLike) -> str:
    """The input format of a file given to ``fpscan recon`` or ``fpscan unmix`` without
    ``--format``, from its content (``fpscan.service.storage.loader.detect_format``).

    Parameters
    ----------
    path : str or os.PathLike
        The input file.

    Returns
    -------
    str
        The name of its input format (``"fpscan"``, ``"npy"``, ``"kwave-hdf5"``, ...).

    Raises
    ------
    ModuleNotFoundError
        The reader's dependencies are not installed (h5py: the driver extra); the message
        says to give ``--format``.
    ValueError
        No input format fits, or the file is not data to reconstruct; the message starts
        with ``path``.
    """
    try:
        from fpscan.service.storage.loader import detect_format
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError(f"no module {exc.name} to tell the file's format: give --format",
                                  name=exc.name) from None

    try:
        return detect_format(path)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def add_server_options(parser: argparse._ActionsContainer, *, required: bool = False) -> None:
    """Declare ``--server URL`` (default ``$FPSCAN_SERVER``) and ``--token`` (default
    ``$FPSCAN_TOKEN``) on ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group
        Where the options go.
    required : bool, optional
        ``--server`` must be given when ``$FPSCAN_SERVER`` is not set (a command that only
        works against a server); default False (without it the command works locally).
    """
    parser.add_argument(
        "--server", metavar="URL", default=os.environ.get("FPSCAN_SERVER") or None,
        required=required and not os.environ.get("FPSCAN_SERVER"),
        help="fpscan server, e.g. http://127.0.0.1:8000 (default: $FPSCAN_SERVER"
             + ("" if required else "; without it the command works locally") + ")",
    )
    parser.add_argument(
        "--token", default=None,
        help="bearer token for the server (default: $FPSCAN_TOKEN)",
    )


def default_dtype() -> str:
    """The reconstruction precision used when none is asked for.

    Read from the module that owns it, ``fpscan.service.recon.limits`` (the same for ``fpscan
    recon``, the server and the web page), which imports nothing heavy: ``fpscan serve`` spawns
    its workers that much sooner.

    Returns
    -------
    str
        ``fpscan.service.recon.limits.DEFAULT_DTYPE``; on a client-only install (no ``service``
        package) ``"float32"``, the value the server states in its methods' options schemas.
    """
    try:
        from fpscan.service.recon.limits import DEFAULT_DTYPE
    except ImportError:
        return "float32"
    return DEFAULT_DTYPE


#: top-level modules of the optional extras (pyproject.toml) -> the extra that installs them
EXTRA_OF_MODULE = {
    **dict.fromkeys(["numpy", "scipy", "finufft", "numba", "h5py", "serial", "cobs", "pint",
                     "matplotlib", "PIL", "tifffile", "ome_zarr", "zarr", "pylops", "pyproximal"], "driver"),
    **dict.fromkeys(["fastapi", "starlette", "uvicorn", "multipart", "python_multipart", "sse_starlette",
                     "distributed", "dask", "pydantic_settings", "psutil"], "server"),
}


def missing_extra(exc: BaseException) -> str | None:
    """The extra whose absence an import error shows.

    Parameters
    ----------
    exc : BaseException
        The error: a ``ModuleNotFoundError`` (or an ``ImportError`` naming its module) for one
        of the optional dependencies in :data:`EXTRA_OF_MODULE`, or anything else.

    Returns
    -------
    str or None
        ``"driver"`` or ``"server"``; None for any other error.
    """
    name = getattr(exc, "name", None)
    if not isinstance(exc, ImportError) or not name:
        return None
    return EXTRA_OF_MODULE.get(name.split(".")[0])


def needs_extra(args: argparse.Namespace, extra: str, detail: str = "") -> int:
    """Say in one line on stderr that ``fpscan <command>`` (as asked) needs the ``extra``
    install (``pip install 'fpscan[<extra>]'``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (its ``command`` names the sub-command).
    extra : str
        The extra's name (``"driver"``, ``"server"``).
    detail : str, optional
        What is missing, in parentheses after the reason (default none).

    Returns
    -------
    int
        2: a usage error (the command cannot run on this install).
    """
    what = f" ({detail})" if detail else ""
    print(f"fpscan {getattr(args, 'command', '')}: error: this needs the fpscan[{extra}] extra, "
          f"not installed here{what}: pip install 'fpscan[{extra}]'", file=sys.stderr)
    return 2


def speed(value: str) -> float | str:
    """An ``argparse`` ``type=`` for ``--sound-speed``: ``"auto"`` (autofocus) or a speed.

    Parameters
    ----------
    value : str
        The flag's text: ``auto`` (any case), a bare number in m/s, or text with a unit
        (``1.5 mm/us``; :func:`quantity`).

    Returns
    -------
    float or str
        The speed of sound in m/s, or ``"auto"``.

    Raises
    ------
    argparse.ArgumentTypeError
        A bad value (argparse reports it naming the flag: a usage error, exit 2).
    """
    if value.strip().lower() == "auto":
        return "auto"
    return quantity("speed", "sound-speed")(value)


def add_progress_option(parser: argparse.ArgumentParser) -> None:
    """Declare ``--quiet`` / ``-q`` (no progress bar: :class:`ProgressBar`'s ``quiet``) on ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    """
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def make_client(args: argparse.Namespace, *, timeout: float = 60.0) -> Client:
    """The HTTP client of the server the command line names.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line: ``server`` (the URL) and ``token`` (else ``$FPSCAN_TOKEN``).
    timeout : float, optional
        The client's time limit per request, s (default 60).

    Returns
    -------
    fpscan.clients.http.Client
        A new client (the caller closes it: ``with make_client(args) as api``).

    Raises
    ------
    ValueError
        No server given.
    """
    from fpscan.clients.http import Client

    if not getattr(args, "server", None):
        raise ValueError("no server given: pass --server URL or set FPSCAN_SERVER")
    return Client(args.server, token=args.token or os.environ.get("FPSCAN_TOKEN") or None,
                  timeout=timeout)


#: how to give the server's token, in a 401's one line (the server's reason first)
TOKEN_HINT = ("give the server's token with --token TOKEN or the FPSCAN_TOKEN environment variable "
              "(the web page asks for it at its sign-in)")


def client_errors(run: Callable[..., int]) -> Callable[..., int]:
    """Decorator for a sub-command's ``run(args)``: the HTTP client's errors become one line
    on stderr and an exit status.

    Parameters
    ----------
    run : callable
        ``run(args) -> int``.

    Returns
    -------
    callable
        ``run`` wrapped: a ``fpscan.clients.http.FpscanClientError`` is printed (with
        :func:`unreachable_hint`) and gives 2 when the server refused the request as given
        (HTTP 400, 404 an unknown id, or 422: the usage error of the local checks,
        ``fpscan.clients.cli.main``), 1 for the server's state (409), access (401/403), load
        (429) and failures; any other exception passes through. A 401 names how to give the
        token (:data:`TOKEN_HINT`).
    """

    @functools.wraps(run)
    def wrapper(args: argparse.Namespace) -> int:
        try:
            return run(args)
        except Exception as exc:
            # imported here: a command that ran locally never loads the HTTP client (httpx: 0.2 s)
            from fpscan.clients.http import ApiError, AuthError, FpscanClientError
            from fpscan.clients.http.errors import format_detail

            if not isinstance(exc, FpscanClientError):
                raise
            message = str(exc)
            if isinstance(exc, AuthError) and exc.hint:  # how to give the token, in the command line's words
                message = f"HTTP {exc.status_code}: {format_detail(exc.detail)}; {TOKEN_HINT}"
            print(f"fpscan {args.command}: error: {message}{unreachable_hint(args, exc)}", file=sys.stderr)
            return 2 if isinstance(exc, ApiError) and exc.status_code in (400, 404, 422) else 1

    return wrapper


def remember_job(args: argparse.Namespace, job_id: str | None) -> None:
    """Note on ``args`` the job a command has had accepted by the server, so that a server
    that goes away afterwards is reported with the command that reattaches to it
    (:func:`unreachable_hint`).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line; its ``submitted_job`` is set.
    job_id : str or None
        The job's id.
    """
    args.submitted_job = job_id


def unreachable_hint(args: argparse.Namespace, exc: Exception) -> str:
    """What an unreachable server (``fpscan.clients.http.ServerUnavailable``) leaves behind, and the
    command that reattaches: the job a command had accepted (``remember_job``) or names
    (``job_id``) survives in the server's job store (a reconstruction runs again when the
    server restarts, a scan waits there paused); "" for any other error.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (``server``, and ``submitted_job`` or ``job_id`` where known).
    exc : Exception
        The client's error.

    Returns
    -------
    str
        Text to append to the one-line error (starting with ". "), or "".
    """
    from fpscan.clients.http import ServerUnavailable

    if not isinstance(exc, ServerUnavailable):
        return ""
    job = getattr(args, "submitted_job", None) or getattr(args, "job_id", None)
    server = getattr(args, "server", None) or "URL"
    if not job:
        return (f". Is `fpscan serve` running at {server}? Jobs it accepted before are kept in its job store "
                f"(its data folder) and go on when it is started again")
    return (f". Job {job} is kept in the server's job store (its data folder): when the server runs again a "
            f"reconstruction is run again and a scan waits, paused; reattach with `fpscan jobs wait {job} "
            f"--server {server}` (a paused scan: `fpscan jobs resume {job} --server {server}` first)")


def _complete(progress: dict) -> bool:
    """Whether a progress report says its work is all done: fraction 1, or every point."""
    total = progress.get("points_total")
    return float(progress.get("fraction") or 0.0) >= 1.0 or bool(total and progress.get("points_done") == total)


def _fmt_eta(seconds: float | None) -> str:
    if seconds is None or seconds != seconds or seconds < 0:
        return "--:--"
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"


def _iteration_detail(progress: dict) -> str:
    """An iterative method's stopping rule against its tolerance (``image change 0.021
    (stops below 0.005)``) from the progress fields of ``fpscan.service.progress.iteration_fields``;
    "" without them or on a client-only install."""
    if progress.get("stop_value") is None:
        return ""
    try:
        from fpscan.service.progress import describe_iteration
    except ImportError:  # pragma: no cover -- a client-only install: the iteration count says enough
        return ""
    text = describe_iteration(progress) or ""
    return text.partition(", ")[2]


def describe_progress(progress: dict, *, with_fraction: bool = True) -> str:
    """One line for a job's progress.

    Parameters
    ----------
    progress : dict
        A job's progress (``stage``, ``fraction``, ``points_done``, ``points_total``,
        ``rate_per_s``, ``eta_s`` and ``eta_max_s`` in s, ``iterations_left_max`` and
        ``eta_basis``, an iterative method's iteration fields, ``faults_recovered``), any of
        them absent.
    with_fraction : bool, optional
        Show the percentage when there is no point count (default True).

    Returns
    -------
    str
        Stage, an iterative method's stopping rule against its tolerance, points done/total,
        points/s, ETA (the server's, or the one estimated by :class:`ProgressBar`; an iterative
        method's with its bound, the iterations left at most) and, without a point count, the
        percentage; two spaces between the parts.
    """
    parts = []
    stage = progress.get("stage")
    if stage:
        parts.append(str(stage))
    if str(stage or "").startswith("iteration"):
        detail = _iteration_detail(progress)
        if detail:
            parts.append(detail)
    done, total = progress.get("points_done"), progress.get("points_total")
    if total:
        parts.append(f"{done or 0}/{total} points")
    rate = progress.get("rate_per_s")
    if rate:
        parts.append(f"{rate:.0f} A-lines/s")  # rate_per_s counts A-lines (points × wavelengths)
    if progress.get("eta_s") is not None and progress.get("stage") not in ("done", "aborted"):
        most, limit = progress.get("iterations_left_max"), progress.get("eta_max_s")
        if most is not None and progress.get("eta_basis") == "stopping rule":  # an estimate, and its bound
            at_rate = f", ~{_fmt_eta(limit)} at the current rate" if limit is not None else ""
            parts.append(f"ETA ~{_fmt_eta(progress.get('eta_s'))} (estimate: stopping rule; "
                         f"at most {most} more iteration{'s' if most != 1 else ''}{at_rate})")
        elif most is not None and progress.get("eta_basis") == "earliest stop":  # a lower bound
            parts.append(f"ETA ≥ {_fmt_eta(progress.get('eta_s'))} (the earliest the rule can stop; "
                         f"at most {most} more iteration{'s' if most != 1 else ''})")
        elif most is not None:  # the time to the iteration limit at the measured rate
            parts.append(f"ETA {_fmt_eta(progress.get('eta_s'))} (to the iteration limit)")
        else:
            parts.append(f"ETA {_fmt_eta(progress.get('eta_s'))}")
    frac = progress.get("fraction")
    if with_fraction and frac is not None and not total:
        parts.append(f"{100 * float(frac):.0f}%")
    if progress.get("faults_recovered"):
        parts.append(f"{progress['faults_recovered']} faults recovered")
    return "  ".join(parts)


#: seconds between progress lines when stderr is not a terminal (logs, CI, a scheduler);
#: ``$FPSCAN_PROGRESS_PERIOD`` overrides it (0: a line for every progress report)
PROGRESS_PERIOD_S = 5.0


def progress_period() -> float:
    """The period of progress lines off a terminal (:class:`ProgressBar`).

    Returns
    -------
    float
        Seconds: ``$FPSCAN_PROGRESS_PERIOD`` (a number >= 0; 0 a line for every report), or
        :data:`PROGRESS_PERIOD_S` when it is unset or empty.

    Raises
    ------
    ValueError
        ``$FPSCAN_PROGRESS_PERIOD`` is not a number >= 0 (named in the message).
    """
    text = os.environ.get("FPSCAN_PROGRESS_PERIOD", "").strip()
    if not text:
        return PROGRESS_PERIOD_S
    try:
        period = float(text)
    except ValueError:
        period = -1.0
    if not period >= 0:
        raise ValueError(f"FPSCAN_PROGRESS_PERIOD must be a number of seconds >= 0, got {text!r}")
    return period


def _stage_kind(stage: object) -> str:
    """A stage without its counter (``"iteration 3/50"`` -> ``"iteration"``): the step that
    starts a new progress line (``fpscan.service.progress.stage_kind``)."""
    from fpscan.service.progress import stage_kind

    return stage_kind(stage)


class ProgressBar:
    """A progress bar fed with job progress dicts (``fraction, stage, points_done,
    points_total, rate_per_s, eta_s``): ``with ProgressBar("scan") as bar: bar(p)``.

    Draws with ``rich`` on a terminal (stderr): bar, percentage, stage, points, ETA. Off a
    terminal it prints a line (stage, %, points, ETA) when the stage changes and at least
    every ``period`` s (default :func:`progress_period`) while the job runs, even between
    reports; ``quiet`` draws nothing. The ETA is the server's (``eta_s``) or estimated here
    by the one model of ``fpscan.service.progress.Eta`` (an iterative method's from its measured
    time per iteration, moving at most 2x between updates), counted down between reports and
    never shown under 5 s for longer than 5 s (``fpscan.service.progress.Countdown``). :meth:`finish` ends the bar
    with the outcome (``"converged after 37 iterations"``) rather than the last stage.

    Parameters
    ----------
    label : str
        What the bar shows first (``"scan"``, ``"recon 1a2b3c4d"``).
    quiet : bool, optional
        Draw nothing (``--quiet``); default False.
    stream : file-like, optional
        Where to draw; default ``sys.stderr``.
    period : float, optional
        Off a terminal, the longest time between progress lines, s; default
        :func:`progress_period`.

    Attributes
    ----------
    label, quiet, stream, period
        As given (``period`` resolved).
    """

    def __init__(self, label: str, *, quiet: bool = False, stream: TextIO | None = None,
                 period: float | None = None) -> None:
        self.label = label
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.period = progress_period() if period is None else float(period)
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._last_stage: str | None = None
        self._printed: tuple[float, str | None] = (0.0, None)  # the last line's fraction and stage
        from fpscan.service.progress import Countdown, Eta

        self._eta = Eta()
        self._countdown = Countdown()  # the ETA shown, counted down between reports
        self._latest: dict | None = None
        self._latest_at = 0.0
        self._printed_at = 0.0
        import threading  # here, not at import: `fpscan --help` starts faster

        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None  # prints between reports

    def __enter__(self) -> ProgressBar:
        if self.quiet:
            return self
        if not self.stream.isatty():
            if self.period > 0:  # period 0: a line for every report, none in between
                import threading

                self._ticker = threading.Thread(target=self._tick, name="progress-lines", daemon=True)
                self._ticker.start()
            return self
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        bar = self._progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(),
            TextColumn("{task.percentage:>5.1f}%"), TextColumn("{task.fields[info]}"),
            TextColumn("elapsed"), TimeElapsedColumn(), console=Console(file=self.stream), transient=False,
        )
        bar.__enter__()
        self._task = bar.add_task(self.label, total=1.0, info="")
        return self

    def __call__(self, progress: dict) -> None:
        if self.quiet or not isinstance(progress, dict):
            return
        progress = dict(progress)
        frac = progress.get("fraction")
        if frac is None and progress.get("points_total"):
            frac = (progress.get("points_done") or 0) / progress["points_total"]
            progress["fraction"] = frac
        now = time.monotonic()
        if progress.get("eta_s") is None and frac is not None:
            from fpscan.service.progress import stage_of

            progress["eta_s"] = self._eta(float(frac), stage_of(progress))  # with the rule's numbers, as the worker's
            if progress["eta_s"] is not None and self._eta.bound_iterations is not None:
                progress.update(iterations_left_max=self._eta.bound_iterations, eta_max_s=self._eta.limit_s,
                                eta_basis=self._eta.basis)
        with self._lock:  # what is shown of the ETA: never under 5 s for longer than 5 s
            progress["eta_s"] = self._countdown.set(progress.get("eta_s"), now)
        if self._progress is not None and self._task is not None:
            self._progress.update(self._task, info=describe_progress(progress, with_fraction=False),
                                  completed=None if frac is None else float(frac))
            return
        with self._lock:
            self._latest, self._latest_at = progress, now
            kind = _stage_kind(progress.get("stage"))
            # once a line at 100 % is out, the pipeline's closing "reconstructing 100%" and the
            # same ending again (finish) add nothing to a log
            ended = (frac is not None and float(frac) >= 1.0 and self._printed[0] >= 1.0
                     and progress.get("stage") in ("reconstructing", self._printed[1]))
            if not ended and (kind != self._last_stage or now - self._printed_at >= self.period):
                self._last_stage = kind
                self._print(progress, now)

    def report(self, fraction: float, stage: str) -> None:
        """The bar as a ``fpscan.service.progress.Progress``: ``report(fraction, stage)`` (a local
        reconstruction's callback) shows as the job progress ``{"fraction", "stage"}``, with
        an iterative method's iteration fields (``fpscan.service.progress.iteration_fields``)."""
        from fpscan.service.progress import IterationStage, iteration_fields

        fields = iteration_fields(stage) if isinstance(stage, IterationStage) else {}
        self({"fraction": fraction, "stage": str(stage), **fields})

    def finish(self, text: str) -> None:
        """End the bar at 100 % showing ``text`` (how the work ended) instead of its last stage."""
        self({"fraction": 1.0, "stage": text, "eta_s": None})

    def _print(self, progress: dict, now: float) -> None:
        """One progress line (the caller holds the lock)."""
        self._printed_at = now
        self._printed = (float(progress.get("fraction") or 0.0), progress.get("stage"))
        frac = progress.get("fraction")
        text = describe_progress(progress, with_fraction=False)
        if frac is not None:  # stage, %, then points, rate, ETA
            stage = str(progress["stage"]) if progress.get("stage") else ""
            rest = text[len(stage):].lstrip() if stage and text.startswith(stage) else text
            text = "  ".join(p for p in (stage, f"{100 * float(frac):.0f}%", rest) if p)
        try:
            print(f"{self.label}: {text}", file=self.stream, flush=True)
        except (OSError, ValueError):  # a closed pipe or stream: progress is best effort
            pass

    def _tick(self) -> None:
        """Off a terminal: repeat the latest progress every ``period`` s when no report came,
        unless it is complete (100 %, or every point done): a state that cannot change is
        said once, however long the job's wrap-up takes (a scan's final live preview)."""
        while not self._stop.wait(self.period):
            with self._lock:
                now = time.monotonic()
                if self._latest is not None and now - self._printed_at >= self.period and \
                        not _complete(self._latest):
                    latest = dict(self._latest)
                    # the time since the last report has passed: the ETA counted down (never under
                    # 5 s for longer than 5 s: fpscan.service.progress.Countdown)
                    latest["eta_s"] = self._countdown.read(now)
                    if latest.get("eta_max_s") is not None:
                        latest["eta_max_s"] = max(float(latest["eta_max_s"]) - (now - self._latest_at), 0.0)
                    self._print(latest, now)

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join(timeout=5)
        if self._progress is not None:
            self._progress.__exit__(*exc)


def quantity(kind: str, name: str) -> Callable[[str], float]:
    """An ``argparse`` ``type=`` for a length, time, frequency or speed.

    Parameters
    ----------
    kind : str
        The quantity: ``"length"``, ``"time"``, ``"frequency"`` or ``"speed"``
        (``fpscan.driver.units.parse_quantity``).
    name : str
        The value's name in messages.

    Returns
    -------
    callable
        ``parse(text) -> float``: the value in SI units (m, s, Hz, m/s); a bare number is SI,
        text may carry a unit (``60um``, ``3.6 mm``, ``8ns``, ``500 Hz``). A bad value raises
        ``argparse.ArgumentTypeError`` naming it (a usage error, exit 2), as does a unit where
        the driver extra (pint) is not installed.
    """
    import argparse

    from fpscan.driver.units import parse_quantity

    def parse(text: str) -> float:
        try:
            return parse_quantity(text, kind, name=name)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        except ImportError as exc:  # a unit needs pint: the driver extra
            if missing_extra(exc) is None:
                raise
            raise argparse.ArgumentTypeError(
                f"{name}: reading units needs the fpscan[{missing_extra(exc)}] extra, not installed here; "
                f"give a bare SI number instead") from None

    parse.__name__ = kind  # argparse names the type in its messages
    return parse


def seconds(name: str) -> Callable[[str], float]:
    """An ``argparse`` ``type=`` for a time limit: a finite number of seconds above 0.

    Parameters
    ----------
    name : str
        The option's name in messages (``--timeout``).

    Returns
    -------
    callable
        ``parse(text) -> float`` (s); NaN, an infinity, 0 or a negative value raise
        ``argparse.ArgumentTypeError`` naming ``name`` (a usage error, exit 2).

    Examples
    --------
    >>> from fpscan.clients.cli.common import seconds
    >>> seconds("--timeout")("2.5")
    2.5
    >>> seconds("--timeout")("nan")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: --timeout must be a finite number of seconds > 0, got 'nan'
    """
    import argparse
    import math

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{name} must be a finite number of seconds > 0, got {text!r}")
        return value

    parse.__name__ = "seconds"
    return parse


def seed(text: str) -> int:
    """``argparse`` ``type=`` of a random seed: an integer >= 0 (numpy's ``default_rng`` takes no
    other); anything else raises ``argparse.ArgumentTypeError`` (a usage error, exit 2).

    Examples
    --------
    >>> from fpscan.clients.cli.common import seed
    >>> seed("7")
    7
    >>> seed("-1")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: a seed is an integer >= 0, got '-1'
    """
    import argparse

    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"a seed is an integer >= 0, got {text!r}")
    return value


def format_bytes(n: float) -> str:
    """A number of bytes with a binary prefix.

    Parameters
    ----------
    n : float
        Bytes.

    Returns
    -------
    str
        ``"512 B"``, ``"1.5 MiB"``, ... (GiB for anything larger).
    """
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(n) < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover - the loop returns at GiB


def check_out_writable(path: str | os.PathLike, flag: str = "--out") -> None:
    """Refuse, before any work, an output ``path`` (a result folder or a file) that cannot be
    written: its parent folder is created if missing and must take a new entry (tried with a
    temporary folder there, removed at once: permissions alone do not say it, e.g. for root
    in ``/proc``).

    Parameters
    ----------
    path : str or os.PathLike
        The output the command will write.
    flag : str, optional
        The flag that named it, for the message (default ``"--out"``).

    Raises
    ------
    UsageError
        (exit 2) The folder cannot take the output: naming ``flag``, the folder and the reason.
    """
    import tempfile
    from pathlib import Path

    parent = Path(path).absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryDirectory(prefix=".fpscan-write-check-", dir=parent).cleanup()
    except OSError as exc:
        raise UsageError(f"{flag} {path}: cannot write in {parent} ({exc.strerror or exc})") from None


def full_job_id(api: Client, job_id: str) -> str:
    """The full id of the job ``job_id`` names.

    A unique prefix, as ``fpscan jobs list`` shows ids, works wherever a job id does: the
    server resolves it in a job's path, this for an id sent in a request's body (``--scan-job``).

    Parameters
    ----------
    api : fpscan.clients.http.Client
        The server's client.
    job_id : str
        A job's id or a unique prefix of it.

    Returns
    -------
    str
        The job's full id.

    Raises
    ------
    fpscan.clients.http.FpscanClientError
        The client's errors: ``NotFound``; ``Conflict`` naming the matches of an ambiguous prefix.
    """
    from fpscan.clients.http import field_of

    return str(field_of(api.get_job(job_id), "id"))


def delete_each(ids: Sequence[str], delete: Callable[[str], Mapping[str, Any]],
                what: Callable[[Mapping[str, Any]], str] = lambda gone: "") -> int:
    """Delete each of ``ids``, printing one line each on stdout ("ID: deleted (WHAT N MiB
    freed)") and a total when there were several.

    Parameters
    ----------
    ids : sequence of str
        The ids to delete.
    delete : callable
        ``delete(id) -> Mapping``: a dataset or job deletion of the HTTP client, answering a
        mapping with ``bytes_freed``.
    what : callable, optional
        ``what(answer) -> str``: the kind, before the size (default none).

    Returns
    -------
    int
        The bytes freed in all.

    Raises
    ------
    fpscan.clients.http.FpscanClientError
        A refused deletion (:func:`client_errors` reports it); the ones before it are done.
    """
    freed = 0
    for item in ids:
        gone = delete(item)
        n = int(gone.get("bytes_freed") or 0)
        freed += n
        print(f"{item}: deleted ({what(gone)}{format_bytes(n)} freed)")
    if len(ids) > 1:
        print(f"{format_bytes(freed)} freed in all")
    return freed
