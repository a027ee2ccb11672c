"""`fpscan export`: a scan file or a reconstruction result in another format, locally or from a
server's job.

The export formats are the registry's (``fpscan.service.formats.export_formats``: IPASC from a scan
file, OME-TIFF and OME-Zarr from a result ``volume.h5``, the files themselves, and whatever
format module is added): ``--format`` names one; without it, the file's (or the job's) first
export that is not the file itself. Locally the file's format is detected from its content and
written by ``fpscan.service.formats.export_file``; with ``--server`` the job's export is downloaded
(``GET /api/jobs/{job_id}/export/{format}``: the job's ``export_<format>`` links, its default
first), a folder export (OME-Zarr) unpacked.
"""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import UsageError, add_server_options, client_errors

__all__ = ["COMMAND", "HELP", "add_arguments", "run"]

COMMAND = "export"
HELP = ("export a scan file (IPASC, ...) or a reconstruction result (OME-TIFF, OME-Zarr, ...: physical voxel "
        "sizes), locally or from a server's job")


def _formats() -> tuple[dict, str]:
    """The registry's export formats (name -> Format) and their help text; none on a
    client-only install (the server checks the name)."""
    try:
        from fpscan.service.formats import FORMATS, export_formats
    except ImportError:
        return {}, ""
    fmts = {n: FORMATS[n] for n in export_formats()}
    return fmts, "; ".join(f"{n}: {f.title} (from {FORMATS[f.export_from].what})" for n, f in fmts.items()
                           if f.export_from)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    fmts, described = _formats()
    parser.add_argument("scan", nargs="?", metavar="FILE",
                        help="scan file or result volume.h5 to export locally")
    parser.add_argument("--job", default=None, metavar="JOB_ID",
                        help="with --server: the scan or reconstruction job whose file to export")
    parser.add_argument("--out", "-o", default=None,
                        help="output file or folder (default: <name><the format's suffix>, e.g. scan_ipasc.h5, "
                             "volume.ome.tif)")
    parser.add_argument("--format", default=None, choices=list(fmts) or None,
                        help="export format (default: the file's first export other than itself: IPASC for a "
                             f"scan file, OME-TIFF for a result){'. ' + described if described else ''}")
    add_server_options(parser)


def _default_export(source: str) -> str:
    """The export of a file of format ``source`` without ``--format``: its first export
    (registration order) other than the file itself. Raises UsageError when it has none."""
    from fpscan.service.formats import FORMATS, export_formats

    others = [n for n in export_formats(source) if n != source]
    if not others:
        raise UsageError(f"{FORMATS[source].what} has no export")
    return others[0]


@client_errors
def run(args: argparse.Namespace) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        The exit status: 0 on success. Errors of the client become exit 1, or 2 when the server refused
        the request as given (``fpscan.clients.cli.common.client_errors``); other refused input and
        failures raise (:func:`fpscan.clients.cli.main` reports them and sets the status).
    """
    if args.server:
        return _remote(args)
    if args.job:
        raise UsageError("--job needs --server")
    if not args.scan:
        raise UsageError("no file given (or use --server URL --job JOB_ID)")
    from pathlib import Path

    from fpscan.service.formats import FORMATS, detect, export_file, export_formats

    src = Path(args.scan)
    if src.is_dir():
        inside = src / "volume.h5"
        hint = f": give its volume, fpscan export {inside}" if inside.is_file() else ""
        raise UsageError(f"{src} is a folder, not a file{hint}")
    if not src.is_file():
        raise UsageError(f"no such file: {src}")
    try:
        source = detect(src)
    except ValueError as exc:
        raise UsageError(f"{src}: {exc}") from None
    if not export_formats(source):
        raise UsageError(f"{src} is {FORMATS[source].what}: nothing to export (give a scan file or a result "
                         "volume.h5)")
    name = args.format or _default_export(source)
    out = Path(args.out or src.with_name(f"{src.name.removesuffix('.h5')}{FORMATS[name].suffix}"))
    if out.exists() and out.resolve() == src.resolve():
        raise UsageError("the output would overwrite the file it exports")
    try:
        export_file(src, out, name)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    print(out)
    return 0


def _remote(args: argparse.Namespace) -> int:
    """``--server``: the job's export downloaded (its default export without ``--format``)."""
    from pathlib import Path

    from fpscan.clients.cli.common import full_job_id, make_client
    from fpscan.clients.http import field_of

    if not args.job:
        raise UsageError("with --server give the job: --job JOB_ID")
    if args.scan:
        raise UsageError("give either a local file or --server with --job, not both")
    with make_client(args, timeout=300) as api:
        job_id = full_job_id(api, args.job)
        links = field_of(api.get_job(job_id), "links") or {}
        fmts = {f["name"]: f for f in api.formats()}
        offered = [k.removeprefix("export_") for k in links if k.startswith("export_")]
        if not offered:
            raise UsageError(f"job {job_id} has nothing to export (yet)")
        # the job's file exported as itself, or its first other export (the local rule)
        name = args.format or next((n for n in offered if n not in fmts or fmts[n].export_from != n), offered[0])
        if name not in offered:
            raise UsageError(f"job {job_id} exports {', '.join(offered)}, not {name}")
        out = Path(args.out or f"{job_id}{fmts[name].suffix if name in fmts else ''}")
        api.export(job_id, name, out)
    print(out)
    return 0
