"""`fpscan unmix`: reconstruct every excitation wavelength and unmix HbO2/Hb (THb, sO2).

Input: one multi-wavelength scan file (every A-line at every wavelength), or one file
per wavelength (any format ``fpscan recon`` reads) with ``--wavelengths`` in m.
Locally (no ``--server``) the job worker's orchestration runs here
(``fpscan.service.pipeline.run_file``): each wavelength is reconstructed with the one dispatch
(``fpscan.service.pipeline.reconstruct``, the same method and options for all; ``--sound-speed auto``
finds the sound speed once) and unmixed (``fpscan.service.recon.unmix``: NNLS per voxel, same
fluence at every wavelength unless ``--fluence`` is given). ``--out`` receives
``unmix.h5`` (``/hbo2``, ``/hb``, ``/thb``, ``/so2``, ``/mask``), ``so2.png`` and one
result folder per wavelength (``wavelength_<k>/volume.h5`` + MIPs). With ``--server``
the job runs on the server (``POST /api/reconstructions`` with ``unmix``) and the same
files are downloaded.
"""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import (
    UsageError,
    add_progress_option,
    add_server_options,
    check_input_files,
    client_errors,
    quantity,
)

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from pathlib import Path

    from fpscan.service.recon.dataset import GridDataset, PointDataset

__all__ = ["COMMAND", "HELP", "add_arguments", "run"]

COMMAND = "unmix"
HELP = "reconstruct every wavelength and unmix HbO2/Hb into THb and sO2 (masked)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    parser.add_argument("inputs", nargs="*", metavar="INPUT",
                        help="a multi-wavelength scan file, or one file per wavelength (with --wavelengths)")
    parser.add_argument("--wavelengths", type=quantity("length", "wavelength"), nargs="+", default=None,
                        metavar="M", help="excitation wavelength of each INPUT, e.g. 750nm 850nm (bare numbers: m)")
    from fpscan.clients.cli.recon import add_format_option

    add_format_option(parser)
    try:  # the registry's defaults (Method.default_for); a client-only install: the server's
        from fpscan.service.recon.methods import default_for
        defaults = f"{default_for('points')} for scans, {default_for('grid')} for grids"
    except ImportError:
        defaults = "the server's for the data"
    parser.add_argument("--method", default=None, help=f"reconstruction method (default: {defaults})")
    parser.add_argument("--out", default=None, metavar="DIR", help="output folder (default: <input>-unmix/)")
    from fpscan.clients.cli.recon_options import add_load_flags, add_option_flags, add_speed_flags

    add_speed_flags(parser, what=", found once for every wavelength")
    parser.add_argument("--threshold", type=float, default=0.1,
                        help="mask voxels whose THb is below this fraction of the maximum (default 0.1)")
    parser.add_argument("--fluence", type=float, nargs="+", default=None, metavar="J_PER_M2",
                        help="fluence at each wavelength, J/m² (default: assumed equal at every wavelength)")
    g = parser.add_argument_group("the inputs' load options (each format's own; SI units)")
    add_load_flags(g)  # generated from the formats' load options (fpscan.service.formats.load_options)
    # every method's options, generated from the registry (fpscan.service.recon.methods), as fpscan recon's
    add_option_flags(parser.add_argument_group("reconstruction options (the methods that take each are named)"))
    parser.add_argument("--scan-job", default=None, metavar="JOB_ID",
                        help="with --server: unmix this (multi-wavelength) scan job's file (no INPUT)")
    add_server_options(parser)
    add_progress_option(parser)


def _params(args: argparse.Namespace) -> dict:
    from fpscan.clients.cli.recon_options import option_params

    return option_params(args)


def _default_out(args: argparse.Namespace) -> Path:
    from pathlib import Path

    if args.out:
        return Path(args.out)
    if args.scan_job:
        return Path(f"unmix-{args.scan_job}")
    p = Path(args.inputs[0])
    return p.with_name(f"{p.stem}-unmix")


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
    check_input_files(args, args.inputs or [], "give a multi-wavelength scan file or one file per wavelength")
    if not args.scan_job:
        if len(args.inputs) > 1 and (args.wavelengths is None or len(args.wavelengths) != len(args.inputs)):
            raise UsageError(f"{len(args.inputs)} inputs need --wavelengths with {len(args.inputs)} values (m)")
    from fpscan.clients.cli.recon import check_options_early

    check_options_early(args.method, _params(args))
    if args.wavelengths is not None:  # unmixing's own rule (range naming the likely unit: 750 -> 750 nm): exit 2
        try:
            from fpscan.service.recon.unmix import endmember_matrix
        except ImportError:  # a client-only install: the server checks them (422)
            pass
        else:
            endmember_matrix(list(args.wavelengths))
    if args.out:  # before the work, not after it
        from fpscan.clients.cli.common import check_out_writable

        check_out_writable(args.out)
    if args.server:
        return _remote(args)
    return _local(args)


def _local(args: argparse.Namespace) -> int:
    """Unmix here: :func:`fpscan.service.pipeline.run_file` with ``unmix``, the job worker's
    orchestration; this command says what it does and prints the result."""
    import sys

    from fpscan.service.pipeline import run_file

    out = _default_out(args)
    say = (lambda msg: None) if args.quiet else (lambda msg: print(f"unmix: {msg}", file=sys.stderr, flush=True))

    def loaded(ds: GridDataset | PointDataset, method: str) -> None:
        say(f"{len(args.inputs) if len(args.inputs) > 1 else 'every'} wavelength(s) of {', '.join(args.inputs)}, "
            f"method {method}")

    load = {k: getattr(args, k) for k in ("dt", "dx", "dy", "key", "axes")}
    summary = run_file(args.inputs, out, args.method, format=args.format, wavelengths=args.wavelengths,
                       unmix={"threshold": args.threshold, "fluence": args.fluence}, load=load,
                       input_id=",".join(args.inputs), on_loaded=loaded,
                       progress=None if args.quiet else (lambda f, s: say(f"{s} {100 * f:.0f} %")), **_params(args))
    c, t = summary.get("sound_speed"), summary["timings"]
    nm = ", ".join(f"{w * 1e9:g} nm" for w in summary["wavelengths_m"])
    print(f"{out}/unmix.h5  so2.png  {nm}  sO2 median {summary['so2_median']}  "
          f"masked {summary['masked_fraction']:.1%}" + (f"  sound speed {c:.1f} m/s" if c is not None else "")
          + f"  {sum(t.values()):.2f} s")
    return 0


def _remote(args: argparse.Namespace) -> int:
    from fpscan.clients.cli.common import ProgressBar, make_client, sniff_format
    from fpscan.clients.http import field_of

    formats = [args.format or sniff_format(p) for p in args.inputs]
    method = args.method  # None: the server applies fpscan.service.pipeline.default_method, as _local does
    with make_client(args, timeout=300) as api:
        unmix = {"threshold": args.threshold, "fluence": args.fluence}
        if args.scan_job:
            from fpscan.clients.cli.common import full_job_id

            job_id = api.start_unmix(scan_job_id=full_job_id(api, args.scan_job), method=method, params=_params(args), **unmix)
        else:
            fields = {k: getattr(args, k) for k in ("dt", "dx", "dy", "key", "axes")}
            ids = [api.upload_dataset(p, fmt, **fields) for p, fmt in zip(args.inputs, formats, strict=True)]
            job_id = api.start_unmix(dataset_ids=ids, wavelengths=args.wavelengths, method=method,
                                     params=_params(args), **unmix)
        assert job_id is not None  # a 202 names its job (fpscan.clients.http.calls.read_job_id)
        from fpscan.clients.cli.common import remember_job

        remember_job(args, job_id)
        with ProgressBar(f"unmix {job_id[:8]}", quiet=args.quiet) as bar:
            job = api.wait(job_id, on_progress=bar)
        out = _default_out(args)
        out.mkdir(parents=True, exist_ok=True)
        api.download_unmix(job_id, out / "unmix.h5")
        api.download_so2(job_id, out / "so2.png")
    result = (field_of(job, "params") or {}).get("result") or {}
    summary = result.get("unmix") or {}
    masked = summary.get("masked_fraction")
    c = result.get("sound_speed", result.get("c"))  # an older server says c
    print(f"{out}/unmix.h5  so2.png  sO2 median {summary.get('so2_median')}"
          + (f"  masked {masked:.1%}" if masked is not None else "")
          + (f"  sound speed {c:.1f} m/s" if c is not None else "") + f"  job {job_id}")
    return 0
