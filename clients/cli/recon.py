"""`fpscan recon`: reconstruct p0 from a scan file or dataset, locally or on a server.

Locally (no ``--server``) the input is read with ``fpscan.service.storage.loader.load_dataset``
(as the service reads uploads), reconstructed with ``fpscan.service.pipeline.reconstruct`` (the
job worker's call) and written with ``fpscan.service.storage.results.write_result`` (the job
worker's result folder): ``volume.h5`` (``/p0`` ``(n_z, n_y, n_x)``, ``/z``, ``/y``,
``/x`` in m) and ``mip_{xy,xz,yz}.png``. The same input and options give the same volume
locally and on the server (default precision float32 on both).
With ``--plan PLAN.json`` dense input (a k-Wave sensor plane or line, a full-lattice scan) is
first sampled by the plan's sensor mask (``fpscan.service.subsample``: a replay scan's A-lines, with
the plan's weights); with ``--server`` the plan is stored there and the job samples the
uploaded dataset (``plan_id``).
With ``--server`` the file is uploaded (``POST /api/datasets``), reconstructed as a job
(``POST /api/reconstructions``; or ``--scan-job`` reuses a scan job's file) and the
volume and MIPs are downloaded into ``--out``.

A multi-wavelength scan (or IPASC file) is reconstructed at ``--wavelength K`` (an index
into its excitation wavelengths; default the first, index 0: said on stderr and recorded
in the volume's params as ``wavelength_index`` and ``wavelength_nm``) or at every
wavelength with ``--wavelength all``: the same method and options for each, ``--out``
then holds the first wavelength's ``volume.h5`` + MIPs and ``wavelength_<k>/`` for each
(the layout of ``fpscan unmix``; ``fpscan.service.spectral.write_wavelength_results``). With
``--server`` an uploaded file is stored at the one wavelength chosen (``--wavelength K``);
``all`` needs ``--scan-job``.
"""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import (
    UsageError,
    add_progress_option,
    add_server_options,
    check_input_files,
    client_errors,
    sniff_format,
)

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from pathlib import Path

    from fpscan.clients.http import Client
    from fpscan.service.recon.dataset import GridDataset, PointDataset

__all__ = ["COMMAND", "HELP", "add_arguments", "check_options_early", "run", "add_format_option"]

COMMAND = "recon"
HELP = "reconstruct p0 (NEDNER/NER/...) from a scan file or dataset, locally or on a server"



def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    INPUT, ``--format``, ``--method`` (the registry's methods), ``--out``, the load options'
    flags, the speed-of-sound flags, every method's options (``fpscan.clients.cli.recon_options``),
    ``--wavelength``, ``--scan-job``, the server and progress options.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The ``recon`` sub-parser.
    """
    METHODS: dict
    try:
        from fpscan.service.recon.methods import METHODS, default_for
    except ImportError:  # no service package: the server checks the method
        METHODS = {}
    # the registry's defaults (Method.default_for), named in the help when it is there
    defaults = (f"{default_for('grid')} for grid data, {default_for('points')} for sensor points"
                if METHODS else "the server's for the data")

    parser.add_argument("input", nargs="?", help="scan file (HDF5), IPASC file, k-Wave HDF5, k-Wave MAT-file (.mat: "
                                                 "MAT v5/v7/v7.3, as MATLAB or Octave save it) or .npy array; the "
                                                 "format is told from the content (--format lists them)")
    add_format_option(parser)
    methods = "; ".join(f"{m.name}: {m.title}" for m in METHODS.values())
    parser.add_argument("--method", choices=list(METHODS) or None, default=None,
                        help="reconstruction method (default: the pipeline's, fpscan.service.pipeline.default_method: "
                             f"{defaults}; locally and on the server). {methods}. "
                             "Grid methods need every lattice point.")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="output folder (default: <input>-<method>/ or recon-<job>/)")
    g = parser.add_argument_group("the input's load options (each format's own; SI units) and speed of sound")
    from fpscan.clients.cli.recon_options import add_load_flags, add_option_flags, add_speed_flags

    add_load_flags(g)  # generated from the formats' load options (fpscan.service.formats.load_options)
    add_speed_flags(g)
    # every method's options, generated from the registry (fpscan.service.recon.methods)
    add_option_flags(parser.add_argument_group("reconstruction options (the methods that take each are named)"))
    parser.add_argument("--wavelength", type=_wavelength, default=None, metavar="K|all",
                        help="excitation wavelength of a multi-wavelength scan: an index into its wavelengths, or "
                             "'all' (one volume per wavelength, same method and options, in <out>/wavelength_<k>/; "
                             "default: the first, index 0, recorded in the volume's params)")
    parser.add_argument("--scan-job", default=None, metavar="JOB_ID",
                        help="with --server: reconstruct this scan job's file (no INPUT)")
    parser.add_argument("--plan", default=None, metavar="PLAN.json",
                        help="a sparse scan out of dense INPUT (a k-Wave sensor plane or line, or a full-lattice "
                             "scan): reconstruct the A-lines this plan's sensor mask picks out of it, with its "
                             "weights, as a replay scan of INPUT records them (fpscan.subsample); the plan's pitch "
                             "and dt must be the data's and its lattice centred on the data's grid. With --server "
                             "the plan is stored there and the job samples the uploaded dataset")
    add_server_options(parser)
    add_progress_option(parser)


def add_format_option(parser: argparse.ArgumentParser) -> None:
    """``--format``: the input formats of the registry (``fpscan.service.formats``: names and
    titles in the help); on a client-only install any name (the server checks it).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-parser (``fpscan recon``, ``fpscan unmix``); dest ``format``, default None
        (from the file's content).
    """
    try:
        from fpscan.service.formats import FORMATS
        from fpscan.service.storage.loader import input_formats
    except ImportError:  # client-only install: the server checks the format
        choices, described = None, ""
    else:
        choices = input_formats()
        described = ": " + "; ".join(f"{n} = {FORMATS[n].title}" for n in choices)
    parser.add_argument("--format", choices=choices, default=None,
                        help=f"input format (default: from the file's content){described}")


def _wavelength(text: str) -> int | str:
    """``--wavelength``: an index >= 0 or ``all`` (argparse: anything else exits 2)."""
    t = text.strip().lower()
    if t == "all":
        return "all"
    if t.isdigit():
        return int(t)
    raise argparse.ArgumentTypeError(f"must be an index >= 0 into the scan's wavelengths or 'all', got {text!r}")


def check_options_early(method: str | None, params: dict) -> None:
    """Check the options by the kernel's own rules before any file is read.

    With a method, ``fpscan.service.pipeline.method_options``; without ``--method`` (the method is
    the input's default), the values' rules only (``fpscan.service.pipeline.check_option_values``).
    On a client-only install (no ``service``, or a rule whose check needs numpy) nothing is
    checked here: the server applies the same rules (422, exit 2).

    Parameters
    ----------
    method : str or None
        ``--method``; None: not given.
    params : dict
        The options given (``fpscan.clients.cli.recon_options.option_params``).

    Raises
    ------
    fpscan.service.recon.checks.OptionError
        (a ValueError; a usage error, exit 2) A refused option, naming its range, or the
        method's options for one the method does not take.
    """
    try:
        from fpscan.service.pipeline import check_option_values, method_options
    except ImportError:
        return
    try:
        if method is not None:
            method_options(method, params)
        else:
            check_option_values(params)
    except ImportError:  # a rule's kernel check needs numpy (client-only install): the server checks it
        return


def _params(args: argparse.Namespace) -> dict:
    from fpscan.clients.cli.recon_options import option_params

    return option_params(args)


@client_errors
def run(args: argparse.Namespace) -> int:
    """Run this sub-command with the parsed ``args``: locally, or with ``--server`` as a job
    whose volume and MIPs are downloaded (module docstring).

    Client errors (``fpscan.clients.http.FpscanClientError``) are one line on stderr and exit 1,
    or 2 for a request the server refused as given (``fpscan.clients.cli.common.client_errors``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`'s options).

    Returns
    -------
    int
        The exit status (0 on success).

    Raises
    ------
    UsageError
        (exit 2) No INPUT and no ``--scan-job``, both, an INPUT that is no file,
        ``--scan-job`` without ``--server``, an ``--out`` that cannot be written,
        ``--wavelength all`` with ``--server`` without ``--scan-job``.
    fpscan.service.recon.checks.OptionError
        A refused option (:func:`check_options_early`).
    ValueError
        An input whose format cannot be told from its content, or that cannot be loaded.
    ModuleNotFoundError
        No ``--format`` given and the reader that tells the format is not installed (h5py:
        the driver extra); the message says to give ``--format``.
    """
    check_input_files(args, [args.input] if args.input else [],
                      "give a scan file or dataset (or --server with --scan-job)")
    check_options_early(args.method, _params(args))
    if args.plan and args.scan_job:
        raise UsageError("--plan samples dense INPUT data; a scan job's file is already a scan: not with --scan-job")
    if args.out:  # before the work, not after it (the default folder sits beside the input)
        from fpscan.clients.cli.common import check_out_writable

        check_out_writable(args.out)
    # no --method: the pipeline's default for the loaded data (fpscan.service.pipeline.default_method),
    # resolved where the data is read: here locally, by the server with --server
    if args.server:
        return _remote(args, None if args.scan_job else (args.format or sniff_format(args.input)))
    return _local(args, args.format or sniff_format(args.input))


def _default_out(args: argparse.Namespace, method: str) -> Path:
    from pathlib import Path

    if args.out:
        return Path(args.out)
    if args.scan_job:
        return Path(f"recon-{args.scan_job}")
    p = Path(args.input)
    return p.with_name(f"{p.stem}-{method}")


def _local(args: argparse.Namespace, fmt: str) -> int:
    """Reconstruct here: :func:`fpscan.service.pipeline.run_file`, the job worker's orchestration (so the
    same file gives the same folder); this command says what it does and prints the result."""
    import sys
    from pathlib import Path

    from fpscan.clients.cli.common import ProgressBar
    from fpscan.service.pipeline import run_file
    from fpscan.service.recon.dataset import GridDataset, file_wavelengths

    say = (lambda msg: None) if args.quiet else (lambda msg: print(f"recon: {msg}", file=sys.stderr, flush=True))
    say(f"importing {args.input} ({fmt})")

    def loaded(ds: GridDataset | PointDataset, method: str) -> None:
        every = file_wavelengths(ds)
        if every.size > 1 and args.wavelength is None:  # the documented default, said
            say(f"the input has {every.size} wavelengths ({', '.join(f'{w * 1e9:g} nm' for w in every)}): "
                f"reconstructing the first (index 0); choose with --wavelength K or all")
        shape = ds.data.shape if isinstance(ds, GridDataset) else ds.alines.shape
        say(f"reconstructing {'every wavelength ' if args.wavelength == 'all' else ''}with {method} "
            f"(input {list(shape)})")

    load = {"dt": args.dt, "dx": args.dx, "dy": args.dy, "key": args.key, "axes": args.axes, "force": args.force,
            "sound_speed": None if args.sound_speed == "auto" else args.sound_speed}
    plan = _read_plan(args.plan) if args.plan else None
    from fpscan.service.subsample import MaskMismatch

    with ProgressBar(f"recon {args.method or ''}".rstrip(), quiet=args.quiet) as bar:
        try:
            summary = run_file(args.input, lambda m: _default_out(args, m), args.method, format=fmt,
                               wavelength=args.wavelength, load=load, input_id=Path(args.input).name,
                               progress=bar.report, on_loaded=loaded, plan=plan, **_params(args))
        except MaskMismatch as exc:
            raise UsageError(f"--plan {args.plan} cannot sample {args.input}: {exc}") from None
        ended = summary.get("outcome")
        if ended:  # an iterative method: the bar ends on how it ended, not on its last stage
            bar.finish(_head(ended))
    method, out, t = summary["method"], _default_out(args, summary["method"]), summary["timings"]
    times = f"load {t['load_s']:.2f} s  reconstruct {t['reconstruct_s']:.2f} s  write {t['write_s']:.2f} s"
    if args.wavelength == "all":
        for row in summary["wavelengths"]:
            print(f"{out}/wavelength_{row['index']}/volume.h5  p0 {'x'.join(map(str, row['shape']))}  "
                  f"method {method}{_nm(row)}")
        print(f"{len(summary['wavelengths'])} wavelengths  {times}")
        return 0
    af = summary.get("autofocus")
    focus = f"  sound speed {af['sound_speed']:.1f} m/s (autofocus, search {af['time_s']:.2f} s)" if af else ""
    print(f"{out}/volume.h5  p0 {'x'.join(str(n) for n in summary['shape'])}  method {method}"
          f"{_nm(summary['params_used'])}  {times}{focus}")
    if ended:
        print(ended)  # the last line: converged or not, iterations, λ, residual against the noise
    return 0


def _read_plan(path: str) -> dict:
    """``--plan``: the plan file, read and checked (``fpscan.load_plan``); a UsageError naming
    the flag for a file that is missing or not a plan."""
    from fpscan.service.formats.plan import read_plan

    try:
        return read_plan(path)
    except (OSError, ValueError) as exc:
        raise UsageError(f"--plan {path}: {exc}") from None


def _head(ended: str) -> str:
    """The outcome's first clause without the method (``"converged after 37 iterations"``)."""
    return ended.partition(": ")[2].partition(" (")[0].partition(";")[0]


def _outcome_of(job: object, method: str | None) -> str | None:  # a Job model or its dict
    """:func:`fpscan.service.progress.outcome` of a finished job's result (``params.result.params_used``);
    None for a method without iterations, or on a client-only install."""
    from fpscan.clients.http import field_of

    used = ((field_of(job, "params") or {}).get("result") or {}).get("params_used") or {}
    try:
        from fpscan.service.recon.methods import outcome
    except ImportError:  # pragma: no cover -- a client-only install
        return None
    return outcome(used, method)


def _nm(params: dict) -> str:
    """``"  wavelength 850 nm"`` from a result's params (or a wavelength row); "" when unknown."""
    w = params.get("wavelength_nm")
    return f"  wavelength {w:g} nm" if w is not None else ""


def _remote(args: argparse.Namespace, fmt: str | None) -> int:
    from fpscan.clients.cli.common import ProgressBar, make_client

    with make_client(args, timeout=300) as api:
        if args.scan_job:
            from fpscan.clients.cli.common import full_job_id

            job_id = api.start_reconstruction(scan_job_id=full_job_id(api, args.scan_job), method=args.method,
                                              params=_params(args), wavelength=args.wavelength)
        else:
            if args.wavelength == "all":
                raise UsageError("--wavelength all with --server needs --scan-job: an uploaded file is stored at "
                                 "one wavelength (--wavelength K); reconstruct locally or upload once per wavelength")
            from fpscan.driver.units import check_plausible

            check_plausible(dt=args.dt, dx=args.dx, dy=args.dy, sound_speed=None if args.sound_speed == "auto" else args.sound_speed,
                            force=args.force)
            fields = {k: getattr(args, k) for k in ("dt", "dx", "dy", "key", "axes", "wavelength")}
            fields["sound_speed"] = args.sound_speed
            if args.force:
                fields["force"] = True
            if fields["sound_speed"] == "auto":  # a search, not the data's speed: it goes with the reconstruction
                fields["sound_speed"] = None
            plan_id = _store_plan(api, args.plan) if args.plan else None
            assert fmt is not None  # run gives one whenever there is no --scan-job
            dataset_id = api.upload_dataset(args.input, fmt, **fields)
            job_id = api.start_reconstruction(dataset_id=dataset_id, method=args.method,
                                              params=_params(args), plan_id=plan_id)
        if job_id is None:  # a 202 names its job (fpscan.clients.http.calls.read_job_id): this one did not
            raise RuntimeError(f"the server accepted the job (HTTP 202) but named no job id; find it with "
                               f"`fpscan jobs list --server {args.server}`")
        from fpscan.clients.cli.common import remember_job

        remember_job(args, job_id)
        with ProgressBar(f"recon {job_id[:8]}", quiet=args.quiet) as bar:
            job = api.wait(job_id, on_progress=bar)
            from fpscan.clients.http import field_of

            method = (field_of(job, "params") or {}).get("method") or args.method  # as the server resolved it
            ended = _outcome_of(job, method)
            if ended:
                bar.finish(_head(ended))
        out = _default_out(args, method)
        planes = _download(api, job_id, out, None)
        print(f"{out}/volume.h5  job {job_id}  method {method}  MIPs {', '.join(planes)}")
        if ended:
            print(ended)
        if args.wavelength == "all":  # every wavelength's folder, as the job wrote it
            rows = ((field_of(job, "params") or {}).get("result") or {}).get("wavelengths") or []
            for row in rows:
                k = int(row["index"])
                _download(api, job_id, out / f"wavelength_{k}", k)
                print(f"{out}/wavelength_{k}/volume.h5  job {job_id}  method {method}{_nm(row)}")
    return 0


def _store_plan(api: Client, path: str) -> str:
    """``--plan`` with ``--server``: the plan file stored on the server (under its own id)."""
    import json

    from fpscan.clients.http import field_of

    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except (OSError, ValueError) as exc:
        raise UsageError(f"--plan {path}: {exc}") from None
    return str(field_of(api.create_plan(doc), "id"))


def _download(api: Client, job_id: str, folder: Path, wavelength: int | None) -> list[str]:
    """Download a result volume and its MIPs (at ``wavelength`` of an all-wavelength job)
    into ``folder``; returns the MIP planes (a 2-D result has only xz)."""
    api.download_volume(job_id, folder / "volume.h5", wavelength=wavelength)
    planes = []
    for plane in ("xy", "xz", "yz"):
        try:
            api.download_mip(job_id, plane, folder / f"mip_{plane}.png", wavelength=wavelength)
            planes.append(plane)
        except Exception as exc:  # a 2-D result has only the xz MIP
            from fpscan.clients.http import ApiError, NotFound

            if not isinstance(exc, (NotFound, ApiError)) or plane == "xz":
                raise
    return planes
