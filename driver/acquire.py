"""Acquire a plan into a scan file: the one-call form of the host driver.

:func:`acquire` opens the scanner, creates the scan file (or reopens it to resume an
interrupted scan: only the points not yet complete are acquired) and runs
:meth:`fpscan.driver.host.Scanner.scan`. Used by ``fpscan scan`` and the service's scan jobs.
"""
from __future__ import annotations

import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import os
    from collections.abc import Callable

    from fpscan.driver.host import Scanner, ScanProgress, ScanResult

__all__ = ["software_version", "acquire"]


@functools.cache
def software_version() -> str:
    """The installed fpscan version (``0+unknown`` when not installed).

    Read from the first ``fpscan-*.dist-info`` on ``sys.path`` (what ``importlib.metadata``
    finds, without its import time, which would double ``fpscan --version``'s); falls back
    to ``importlib.metadata``. Looked up once a process (listing ``sys.path`` took 4 ms
    of every result file's write): the version of the code this process runs.

    Returns
    -------
    str
        The version string, e.g. ``"1.4.0"``, or ``"0+unknown"``.
    """
    import os
    import sys

    for entry in sys.path:
        try:
            names = [n for n in os.listdir(entry or ".") if n.startswith("fpscan-") and n.endswith(".dist-info")]
        except OSError:
            continue
        for name in sorted(names):
            try:
                with open(os.path.join(entry or ".", name, "METADATA"), encoding="utf-8") as f:
                    for line in f:
                        if line.startswith("Version:"):
                            return line.split(":", 1)[1].strip()
                        if not line.strip():
                            break  # the end of the headers
            except OSError:
                continue
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fpscan")
    except PackageNotFoundError:
        return "0+unknown"


def acquire(port: str, plan: dict | str | os.PathLike, out: str | os.PathLike, *,
            progress: Callable[[ScanProgress], None] | None = None, scanner: Scanner | None = None,
            durable: str = "process", **scanner_options: Any) -> ScanResult:
    """Scan ``plan`` (dict or plan JSON path) on ``port`` into the scan file ``out``.

    If ``out`` exists it must be a scan file of the same plan; the scan resumes from its
    record of completed points. ``scanner``: an already open :class:`~fpscan.driver.host.Scanner`
    (e.g. one whose ``pause``/``abort`` another thread holds); otherwise one is opened with
    ``scanner_options`` and closed at the end. Returns :class:`~fpscan.driver.host.ScanResult`.

    Raises ``ValueError`` (bad plan, file of another plan), :class:`~fpscan.driver.host.DriverError`
    and its subclasses (link failures), ``OSError`` (file system).

    Parameters
    ----------
    port : str
        The scanner's serial port (or the simulator's address), as :class:`~fpscan.driver.host.Scanner`
        takes it; unused when ``scanner`` is given.
    plan : dict or str or Path
        The plan, or the path of its JSON file (:func:`fpscan.driver.plan.load_plan`).
    out : str or Path
        The scan file (HDF5) to create, or to resume when it exists.
    progress : callable, optional
        Called with each :class:`~fpscan.driver.host.ScanProgress` (from the scanning thread).
    scanner : Scanner, optional
        An already open scanner; it is left open at the end.
    durable : str, optional
        The scan file's durability policy, ``"process"`` (default) or ``"fsync"``
        (`fpscan.driver.scanfile`).
    **scanner_options
        Passed to :class:`~fpscan.driver.host.Scanner` when this call opens it.

    Returns
    -------
    ScanResult
        The outcome of the scan (:class:`~fpscan.driver.host.ScanResult`).

    Raises
    ------
    ValueError
        A bad plan, or an existing ``out`` of another plan.
    DriverError
        Link or device failures (:class:`~fpscan.driver.host.DriverError` and its subclasses).
    OSError
        File system errors.
    """
    from fpscan.driver.host import Scanner
    from fpscan.driver.plan import load_plan
    from fpscan.driver.scanfile import ScanFile

    plan = load_plan(plan)
    out = Path(out)
    own = scanner is None
    sc = Scanner(port, **scanner_options) if scanner is None else scanner
    try:
        instrument = sc.identify()
        resume = out.exists()
        if resume:
            sink = ScanFile.open_append(out, plan, durable=durable)
        else:
            sc.upload_plan(plan)  # a plan the device refuses leaves no empty file behind
            sink = ScanFile.create(out, plan, instrument=instrument,
                                   software_version=software_version(), durable=durable)
        try:
            return sc.scan(plan, sink, progress=progress, upload=resume)
        finally:
            sink.close()
    finally:
        if own:
            sc.close()
