"""`fpscan export`: IPASC export of a scan file, locally (``service.formats.ipasc``) or from a
server (``GET /api/scans/{job_id}/ipasc``); OME-TIFF or OME-Zarr export (``--format``) of a
reconstruction result (``service.storage.results.export_volume``, or ``GET
/api/reconstructions/{job_id}/volume.ome.tif`` / ``volume.ome.zarr.zip``) for ImageJ/Fiji
and napari.

The IPASC file is HDF5 written with plain h5py: ``/binary_time_series_data``
``[detectors, samples, wavelengths, measurements]``, ``/meta_data/...`` and
``/meta_data_device/...`` (IPASC data format; SI units).
"""
from __future__ import annotations

from clients.cli._common import UsageError, add_server_options, client_errors

__all__ = ["COMMAND", "HELP", "VOLUME_SUFFIXES", "add_arguments", "run"]

COMMAND = "export"
HELP = ("export a scan file to IPASC HDF5, or a reconstruction result to OME-TIFF or OME-Zarr "
        "(physical voxel sizes), locally or from a server's job")
#: --format → the suffix of the default output name (service.storage.results.EXPORT_FORMATS)
VOLUME_SUFFIXES = {"ome-tiff": ".ome.tif", "ome-zarr": ".ome.zarr"}


def add_arguments(parser):
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser)."""
    parser.add_argument("scan", nargs="?", help="scan file (→ IPASC) or result volume.h5 (→ OME-TIFF / "
                                                "OME-Zarr) to export locally")
    parser.add_argument("--job", default=None, metavar="JOB_ID",
                        help="with --server: the scan job (→ IPASC) or reconstruction job (→ OME-TIFF)")
    parser.add_argument("--out", "-o", default=None,
                        help="output file (default: <scan>_ipasc.h5 / <job>_ipasc.h5, or <name>.ome.tif / "
                             "<name>.ome.zarr, a folder)")
    parser.add_argument("--format", default="ome-tiff", choices=sorted(VOLUME_SUFFIXES),
                        help="format of a reconstruction result's export (default ome-tiff); a scan "
                             "file always exports to IPASC")
    add_server_options(parser)


def _local_export():
    """The service's own IPASC exporter (``service.formats.ipasc.export_scan``)."""
    from service.formats.ipasc import export_scan

    return export_scan


def _is_result(path) -> bool:
    """True for a reconstruction result file (``fpscan-result/1``: detected by the
    registry of formats, ``service.formats.detect``; a file a writer has open in a
    bounded child)."""
    from service.formats import detect

    try:
        return detect(path) == "result"
    except (ValueError, OSError):
        return False


@client_errors
def run(args) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status."""
    from pathlib import Path

    if args.server:
        if not args.job:
            raise UsageError("with --server give the scan job: --job JOB_ID")
        if args.scan:
            raise UsageError("give either a local scan file or --server with --job, not both")
        from clients.cli._common import make_client
        from clients.http import field_of

        with make_client(args, timeout=300) as api:
            if field_of(api.get_job(args.job), "kind") == "recon":
                out = Path(args.out or f"{args.job}{VOLUME_SUFFIXES[args.format]}")
                if args.format == "ome-zarr":
                    api.download_ome_zarr(args.job, out)
                else:
                    api.download_ome_tiff(args.job, out)
            else:
                out = Path(args.out or f"{args.job}_ipasc.h5")
                api.download_ipasc(args.job, out)
        print(out)
        return 0
    if args.job:
        raise UsageError("--job needs --server")
    if not args.scan:
        raise UsageError("no scan file given (or use --server URL --job JOB_ID)")
    scan = Path(args.scan)
    if not scan.is_file():
        raise UsageError(f"no such file: {scan}")
    if _is_result(scan):
        from service.storage.results import export_volume

        out = Path(args.out or scan.with_name(f"{scan.stem}{VOLUME_SUFFIXES[args.format]}"))
        if out.resolve() == scan.resolve():
            raise UsageError("the output would overwrite the result file")
        export_volume(scan, out, args.format)
        print(out)
        return 0
    out = Path(args.out or scan.with_name(f"{scan.stem}_ipasc.h5"))
    if out.resolve() == scan.resolve():
        raise UsageError("the output would overwrite the scan file")
    from service.formats.untrusted import read_bounded

    # written to a temporary sibling, then renamed; a file a writer has open is read in a
    # bounded child (HDF5 can block on its damaged metadata for ever)
    read_bounded(_local_export(), scan, out)
    print(out)
    return 0
