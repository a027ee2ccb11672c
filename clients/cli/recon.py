"""`fpscan recon`: reconstruct p0 from a scan file or dataset, locally or on a server.

Locally (no ``--server``) the input is imported with ``service.storage.datasets``
(as the service imports uploads), reconstructed with ``service.recon`` and written like a
server result (``service.storage.results`` / ``service.storage.render``): ``volume.h5``
(``/p0`` ``(n_z, n_y, n_x)``, ``/z``, ``/y``, ``/x`` in m) and ``mip_{xy,xz,yz}.png``.
With ``--server`` the file is uploaded (``POST /api/datasets``), reconstructed as a job
(``POST /api/reconstructions``; or ``--scan-job`` reuses a scan job's file) and the
volume and MIPs are downloaded into ``--out``.
"""
from __future__ import annotations

from clients.cli._common import add_progress_option, add_server_options, client_errors

COMMAND = "recon"
HELP = "reconstruct p0 (NEDNER/NER/...) from a scan file or dataset, locally or on a server"

FORMATS = ("fpscan", "ipasc", "kwave-hdf5", "npy")
METHODS = ("nedner", "ner", "linear", "nearest", "cubic", "kwave")


def add_arguments(parser):
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser)."""
    parser.add_argument("input", nargs="?", help="scan file (HDF5), IPASC file, k-Wave HDF5 or .npy array")
    parser.add_argument("--format", choices=FORMATS, default=None,
                        help="input format (default: from the file: .npy, IPASC, k-Wave HDF5 or fpscan scan)")
    parser.add_argument("--method", choices=METHODS, default=None,
                        help="reconstruction method (default: nedner for scans/IPASC, ner for grids)")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="output folder (default: <input>-<method>/ or recon-<job>/)")
    g = parser.add_argument_group("data spacings (npy and k-Wave inputs; SI units)")
    g.add_argument("--dt", type=float, default=None, help="sample interval, s")
    g.add_argument("--dx", type=float, default=None, help="lateral spacing along x, m")
    g.add_argument("--dy", type=float, default=None, help="lateral spacing along y, m (default dx)")
    g.add_argument("--c", type=float, default=None, help="speed of sound, m/s (default: the input's or 1500)")
    g.add_argument("--key", default=None, help="HDF5 dataset path in a k-Wave file (default sensor_data/clean)")
    g = parser.add_argument_group("reconstruction options")
    g.add_argument("--eps", type=float, default=None, help="NUFFT tolerance (default 1e-6)")
    g.add_argument("--dtype", choices=("float32", "float64"), default=None, help="working precision")
    g.add_argument("--upsample", type=int, default=None, help="lateral upsampling factor")
    g.add_argument("--positivity", action="store_true", help="clip negative p0 to 0")
    g.add_argument("--n-z", type=int, default=None, help="output depth samples (default n_t)")
    g.add_argument("--dz", type=float, default=None, help="output depth spacing, m (default c*dt)")
    parser.add_argument("--scan-job", default=None, metavar="JOB_ID",
                        help="with --server: reconstruct this scan job's file (no INPUT)")
    add_server_options(parser)
    add_progress_option(parser)


def _sniff_format(path) -> str:
    """The input's format from its content (``service.storage.datasets.detect_format``)."""
    from service.storage.datasets import detect_format

    try:
        return detect_format(path)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _params(args) -> dict:
    params = {}
    for name in ("eps", "dtype", "upsample", "n_z", "dz", "c"):
        value = getattr(args, name)
        if value is not None:
            params[name] = value
    if args.positivity:
        params["positivity"] = True
    return params


@client_errors
def run(args) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status."""
    from pathlib import Path

    if args.scan_job and not args.server:
        raise ValueError("--scan-job needs --server")
    if args.scan_job and args.input:
        raise ValueError("give either INPUT or --scan-job, not both")
    if not args.scan_job:
        if not args.input:
            raise ValueError("no input: give a scan file or dataset (or --server with --scan-job)")
        if not Path(args.input).is_file():
            raise ValueError(f"no such file: {args.input}")
    fmt = None if args.scan_job else (args.format or _sniff_format(args.input))
    method = args.method or ("nedner" if fmt in (None, "fpscan", "ipasc") else "ner")
    if args.server:
        return _remote(args, fmt, method)
    return _local(args, fmt, method)


def _default_out(args, method: str):
    from pathlib import Path

    if args.out:
        return Path(args.out)
    if args.scan_job:
        return Path(f"recon-{args.scan_job}")
    p = Path(args.input)
    return p.with_name(f"{p.stem}-{method}")


def reconstruct_dataset(ds, method: str, params: dict):
    """Run ``service.recon`` on a ``service.storage.datasets`` dataset.

    ``method``: ``nedner`` (NEDNER-NUFFT, ``reconstruct_points``; any input) or a grid
    method (``ner``, ``linear``, ``nearest``, ``cubic``; regular grids only). ``params``:
    ``eps``, ``dtype`` ("float32"/"float64"), ``upsample``, ``positivity``, ``n_z``,
    ``dz`` (m), ``c`` (m/s, overrides the input's). Returns the ``Image``. Raises
    ``ValueError`` when the method does not fit the input."""
    import numpy as np

    from service import recon

    opts = {k: params[k] for k in ("eps", "upsample", "positivity", "n_z", "dz") if params.get(k) is not None}
    if params.get("dtype"):
        opts["dtype"] = np.float32 if params["dtype"] == "float32" else np.float64
    if getattr(ds, "t0", 0.0):
        opts["t0"] = float(ds.t0)
    c = float(params.get("c") or ds.c)
    if ds.kind == "grid":
        if method == "nedner":
            axes = ds.axes()
            data = ds.data
            if data.ndim == 2:
                alines, positions = data.T, axes[0][:, None]
            else:
                yy, xx = np.meshgrid(axes[1], axes[0], indexing="ij")
                alines = data.reshape(data.shape[0], -1).T
                positions = np.stack([xx.ravel(), yy.ravel()], axis=1)
            return recon.reconstruct_points(alines, positions, ds.dt, c, grid=axes, method="ner", **opts)
        if ds.data.ndim == 3 and ds.dy is not None:
            opts["dy"] = ds.dy
        return recon.reconstruct_grid(ds.data, ds.dx, ds.dt, c, method=method, **opts)
    if method != "nedner":
        raise ValueError(f"method {method!r} needs data on a full regular grid; use nedner for a sensor mask")
    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no completed A-lines")
    return recon.reconstruct_points(ds.alines, ds.positions, ds.dt, c, weights=ds.weights, grid=ds.grid,
                                    method="ner", **opts)


def write_local_result(out, image, *, input_id: str) -> None:
    """``out/volume.h5`` (``service.storage.results``) and ``out/mip_{plane}.png``
    (``service.storage.render``), written to a temporary folder renamed into place: the
    same files a server-side reconstruction job writes (``service.jobs.work.write_result``)."""
    from service.jobs.work import write_result

    write_result(out, image, input_id=input_id)


def _local(args, fmt: str, method: str) -> int:
    import sys
    import time
    from pathlib import Path

    from service.storage.datasets import load_dataset

    out = _default_out(args, method)
    say = (lambda msg: None) if args.quiet else (lambda msg: print(f"recon: {msg}", file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    say(f"importing {args.input} ({fmt})")
    ds = load_dataset(args.input, fmt, dt=args.dt, dx=args.dx, dy=args.dy, c=args.c, key=args.key)
    t1 = time.perf_counter()
    shape = ds.data.shape if ds.kind == "grid" else ds.alines.shape
    say(f"reconstructing with {method} (input {list(shape)})")
    image = reconstruct_dataset(ds, method, {"method": method, **_params(args)})
    t2 = time.perf_counter()
    say(f"writing {out}/")
    write_local_result(out, image, input_id=Path(args.input).name)
    t3 = time.perf_counter()
    dims = "x".join(str(n) for n in image.p0.shape)
    print(f"{out}/volume.h5  p0 {dims}  load {t1 - t0:.2f} s  reconstruct {t2 - t1:.2f} s  write {t3 - t2:.2f} s")
    return 0


def _remote(args, fmt: str | None, method: str) -> int:
    from clients.cli._common import ProgressBar, make_client

    with make_client(args, timeout=300) as api:
        if args.scan_job:
            job_id = api.start_reconstruction(scan_job_id=args.scan_job, method=method, params=_params(args))
        else:
            fields = {k: getattr(args, k) for k in ("dt", "dx", "dy", "c", "key")}
            dataset_id = api.upload_dataset(args.input, fmt, **fields)
            job_id = api.start_reconstruction(dataset_id=dataset_id, method=method, params=_params(args))
        with ProgressBar(f"recon {job_id[:8]}", quiet=args.quiet) as bar:
            api.wait(job_id, on_progress=bar)
        out = _default_out(args, method)
        api.download_volume(job_id, out / "volume.h5")
        planes = []
        for plane in ("xy", "xz", "yz"):
            try:
                api.download_mip(job_id, plane, out / f"mip_{plane}.png")
                planes.append(plane)
            except Exception as exc:  # a 2-D result has only the xz MIP
                from clients.http import ApiError, NotFound

                if not isinstance(exc, (NotFound, ApiError)) or plane == "xz":
                    raise
        print(f"{out}/volume.h5  job {job_id}  MIPs {', '.join(planes)}")
    return 0
