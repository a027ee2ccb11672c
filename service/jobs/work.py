"""The reconstruction job body: runs inside an executor worker (process pool or dask).

``run_reconstruction(spec)`` reads the job's input, calls ``service.recon`` and writes the
result folder atomically (temporary folder, then ``os.replace``):

- ``volume.h5``: ``/p0`` (``(n_z, n_y, n_x)`` or ``(n_z, n_x)``, Pa relative to the
  input's units), ``/z``, ``/x`` (and ``/y``) coordinate vectors in m; attributes
  ``method``, ``params`` (JSON of every parameter used), ``input_id``;
- ``mip_xy.png``, ``mip_xz.png``, ``mip_yz.png`` (3-D) or ``mip_xz.png`` (2-D).

Inputs (``spec["input"]``):
- ``{"kind": "dataset", "path": <dataset.h5>}``: the canonical dataset file written by
  :mod:`service.api.datasets` (layout ``grid``: ``/data`` ``(n_t, n_y, n_x)``/``(n_t, n_x)``
  with ``dt``, ``dx``, ``c`` attributes; layout ``points``: ``/alines`` ``(n, n_t)``,
  ``/positions`` ``(n, 2)``, ``/weights``, ``/grid_x``, ``/grid_y``);
- ``{"kind": "scan", "path": <scan.h5>}``: a scan file (``driver.scanfile.read_scan``);
  only completed points are used, reconstructed on the plan's lattice with NEDNER unless
  a grid method was asked for and every lattice point is present.

Everything here is a plain function of picklable arguments so dask can ship it.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

GRID_METHODS = ("ner", "linear", "nearest", "cubic")
POINT_METHODS = ("nedner",)


def lattice_axes(lattice: dict) -> tuple[np.ndarray, np.ndarray]:
    """Lattice coordinate vectors ``x_i = (i - (n - 1)/2) * pitch`` (docs/architecture.md)."""
    n_x, n_y, pitch = int(lattice["n_x"]), int(lattice.get("n_y", 1)), float(lattice["pitch"])
    x = (np.arange(n_x) - (n_x - 1) / 2.0) * pitch
    y = (np.arange(n_y) - (n_y - 1) / 2.0) * pitch
    return x, y


def load_scan_points(path: str | os.PathLike, *, wavelength_index: int = 0) -> dict:
    """Completed A-lines of a scan file at excitation wavelength ``wavelength_index``
    (default the first) as reconstruction input: ``alines`` ``(n, n_t)``
    (DC-normalised pressure), ``positions`` ``(n, d)`` m, ``weights`` ``(n,)``, ``dt`` s,
    ``c`` m/s, ``grid`` (lattice vectors), ``lattice`` indices ``(n, 2)``, ``lattice_shape``
    ``(n_y, n_x)``, ``n_points`` of the plan."""
    from driver.scanfile import read_scan

    scan = read_scan(path, wavelength_index=wavelength_index)
    done = np.asarray(scan.completed, dtype=bool)
    plan = scan.plan
    lat = plan["lattice"]
    x, y = lattice_axes(lat)
    positions = np.asarray(scan.positions, dtype=np.float64)
    two_d = int(lat.get("n_y", 1)) == 1 or positions.shape[1] == 1
    grid = (x,) if two_d else (x, y)
    if two_d:
        positions = positions[:, :1]
    return {
        "alines": np.asarray(scan.pressure[done]),
        "positions": positions[done],
        "weights": np.asarray(scan.weights, dtype=np.float64)[done],
        "dt": float(scan.dt), "c": float(scan.sound_speed), "grid": grid, "n_points": int(scan.n_points),
        "lattice": np.asarray(scan.indices)[done], "lattice_shape": (int(lat.get("n_y", 1)), int(lat["n_x"])),
        "pitch": float(lat["pitch"]),
    }


def points_to_grid(inp: dict) -> np.ndarray:
    """A-lines at every lattice point → grid data ``(n_t, n_y, n_x)`` (``(n_t, n_x)`` in
    2-D); raises ``ValueError`` if any lattice point is missing."""
    n_y, n_x = inp["lattice_shape"]
    idx = np.asarray(inp["lattice"], dtype=np.int64)
    filled = np.zeros((n_y, n_x), dtype=bool)
    filled[idx[:, 1], idx[:, 0]] = True
    if not filled.all():
        raise ValueError(f"a grid method needs every lattice point; {int((~filled).sum())} of {n_x * n_y} "
                         "are missing (use 'nedner')")
    n_t = inp["alines"].shape[1]
    data = np.empty((n_t, n_y, n_x), dtype=inp["alines"].dtype)
    data[:, idx[:, 1], idx[:, 0]] = inp["alines"].T
    return data[:, 0, :] if n_y == 1 else data


def _recon_options(params: dict, inp: dict | None = None) -> dict:
    opts: dict[str, Any] = {}
    if inp is not None and inp.get("t0"):
        opts["t0"] = float(inp["t0"])
    for key in ("eps", "upsample", "positivity", "dz", "n_z", "t0"):
        if params.get(key) is not None:
            opts[key] = params[key]
    if params.get("dtype"):
        opts["dtype"] = np.float32 if params["dtype"] == "float32" else np.float64
    return opts


def reconstruct_input(inp: dict, params: dict):
    """Run ``service.recon`` on a loaded input; returns its ``Image``. Raises
    ``ValueError`` when the method does not fit the input."""
    from service import recon

    method = params.get("method", "nedner")
    opts = _recon_options(params, inp)
    if inp["layout"] == "grid":
        c = float(params.get("c") or inp["c"])
        if method in POINT_METHODS:
            data = inp["data"]
            if data.ndim == 2:
                x = (np.arange(data.shape[1]) - (data.shape[1] - 1) / 2.0) * inp["dx"]
                grid: tuple[np.ndarray, ...] = (x,)
                alines, positions = data.T, x[:, None]
            else:
                n_y, n_x = data.shape[1:]
                x = (np.arange(n_x) - (n_x - 1) / 2.0) * inp["dx"]
                y = (np.arange(n_y) - (n_y - 1) / 2.0) * inp.get("dy", inp["dx"])
                yy, xx = np.meshgrid(y, x, indexing="ij")
                alines = data.reshape(data.shape[0], -1).T
                positions = np.stack([xx.ravel(), yy.ravel()], axis=1)
                grid = (x, y)
            return recon.reconstruct_points(alines, positions, inp["dt"], c, grid=grid, method="ner", **opts)
        if inp["data"].ndim == 3 and inp.get("dy") is not None:
            opts["dy"] = inp["dy"]
        return recon.reconstruct_grid(inp["data"], inp["dx"], inp["dt"], c, method=method, **opts)
    # points layout
    c = float(params.get("c") or inp["c"])
    if method not in POINT_METHODS and "lattice" in inp:
        return recon.reconstruct_grid(points_to_grid(inp), inp["pitch"], inp["dt"], c, method=method, **opts)
    if method not in POINT_METHODS:
        raise ValueError(f"method {method!r} needs a full regular grid; use 'nedner' for a sensor mask")
    if inp["alines"].shape[0] == 0:
        raise ValueError("no completed A-lines to reconstruct")
    # NEDNER = NUFFT in time ("ner" temporal step) + type-1 NUFFT over the positions
    return recon.reconstruct_points(inp["alines"], inp["positions"], inp["dt"], c, weights=inp.get("weights"),
                                    grid=inp["grid"], method="ner", **opts)


def load_input(spec_input: dict) -> dict:
    """Load a job input (see module docstring) into arrays."""
    import h5py

    if spec_input["kind"] == "scan":
        pts = load_scan_points(spec_input["path"])
        return {"layout": "points", **pts}
    with h5py.File(spec_input["path"], "r") as f:
        layout = f.attrs["layout"]
        layout = layout.decode() if isinstance(layout, bytes) else str(layout)
        out = {"layout": layout, "dt": float(f.attrs["dt"]), "c": float(f.attrs["c"]),
               "t0": float(f.attrs.get("t0", 0.0))}
        if layout == "grid":
            out["data"] = f["data"][...]
            out["dx"] = float(f.attrs["dx"])
            if "dy" in f.attrs:
                out["dy"] = float(f.attrs["dy"])
        else:
            out["alines"] = f["alines"][...]
            out["positions"] = f["positions"][...]
            out["weights"] = f["weights"][...] if "weights" in f else None
            gx = f["grid_x"][...]
            out["grid"] = (gx, f["grid_y"][...]) if "grid_y" in f else (gx,)
            if "lattice" in f:  # lattice indices: a full lattice can use the grid methods
                out["lattice"] = f["lattice"][...]
                out["lattice_shape"] = tuple(int(v) for v in f.attrs["lattice_shape"])
                out["pitch"] = float(f.attrs["pitch"])
    return out


def write_result(out_dir: str | os.PathLike, image, *, input_id: str, extra: dict | None = None) -> dict:
    """Write ``volume.h5`` (``service.storage.results.write_image``, format
    ``fpscan-result/1``) and the MIP PNGs (``service.storage.render.render_mips``) into
    ``out_dir`` atomically: a temporary sibling folder renamed into place. Returns a
    summary dict."""
    from service.storage.render import render_mips
    from service.storage.results import write_image

    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + f".tmp-{os.getpid()}-{time.monotonic_ns()}")
    tmp.mkdir(parents=True)
    try:
        p0 = np.asarray(image.p0)
        write_image(tmp / "volume.h5", image, input_id=input_id)
        pngs = render_mips(p0, image.z, image.x, getattr(image, "y", None))
        for plane, png in pngs.items():
            (tmp / f"mip_{plane}.png").write_bytes(png)
        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"shape": list(p0.shape), "max": float(np.max(p0)) if p0.size else 0.0, "planes": sorted(pngs)}


def report_stage(path: str | None, stage: str, fraction: float) -> None:
    """Write the job's current stage to its progress file (``{"stage", "fraction"}``,
    replaced atomically); the server's job thread turns changes into progress events."""
    if not path:
        return
    import json

    tmp = f"{path}.tmp-{os.getpid()}"
    try:
        with open(tmp, "w") as f:
            json.dump({"stage": stage, "fraction": fraction}, f)
        os.replace(tmp, path)
    except OSError:  # progress is best effort (e.g. a remote worker without the folder)
        pass


def check_memory_limit(inp: dict, params: dict, limit: int) -> None:
    """The admission rule (``service.jobs.queue.estimate_memory``) again, on the input as
    loaded: ValueError with the reason if it needs more than ``limit`` bytes (the
    configured limit, not the memory free now)."""
    from service.jobs.queue import admit, estimate_memory

    if inp["layout"] == "grid":
        d = inp["data"]
        shape = {"n_t": d.shape[0], "n_x": d.shape[-1], "n_y": d.shape[1] if d.ndim == 3 else 1}
    else:
        grid = inp["grid"]
        shape = {"n_t": inp["alines"].shape[1], "n_x": len(grid[0]), "n_y": len(grid[1]) if len(grid) > 1 else 1,
                 "n_points": inp["alines"].shape[0]}
    shape.update(dt=inp["dt"], c=inp["c"])
    admit(estimate_memory(shape, params), limit)


#: Address space a worker may use beyond the memory limit (interpreter, libraries, thread
#: stacks and allocator arenas are reserved, mostly never touched).
ADDRESS_SPACE_BASE = 6 * 2**30


@contextlib.contextmanager
def address_space_limit(limit: int | None):
    """While inside: the process's soft ``RLIMIT_AS`` at ``limit + ADDRESS_SPACE_BASE``, so
    a reconstruction past the limit fails with MemoryError instead of swapping the
    machine; restored after. No-op without ``limit`` or where not supported."""
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        supported = True
    except (ImportError, OSError, ValueError):
        supported = False
    if not limit or not supported:
        yield
        return
    want = int(limit) + ADDRESS_SPACE_BASE
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    try:
        resource.setrlimit(resource.RLIMIT_AS, (want, hard))
    except (OSError, ValueError):
        yield
        return
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def run_reconstruction(spec: dict) -> dict:
    """Executor entry point. ``spec``: ``input`` (see above), ``params`` (method and
    options), ``out_dir``, ``input_id``, optional ``progress_path`` (stages ``loading``,
    ``reconstructing``, ``writing`` are reported there). Returns ``{"shape", "max",
    "timings"}``. Raises ``ValueError`` for inputs the method cannot use."""
    progress = spec.get("progress_path")
    t0 = time.perf_counter()
    report_stage(progress, "loading", 0.1)
    limit = spec.get("memory_limit")
    inp = load_input(spec["input"])
    if limit:
        check_memory_limit(inp, spec["params"], int(limit))
    t1 = time.perf_counter()
    report_stage(progress, "reconstructing", 0.2)
    try:
        with address_space_limit(limit):
            image = reconstruct_input(inp, spec["params"])
    except MemoryError:
        if not limit:  # no limit set: a real out-of-memory
            raise
        raise ValueError(f"the reconstruction ran out of the memory limit of {int(limit) / 2**30:.2f} GiB; "
                         "reduce the size, upsample or n_z, or use float32") from None
    t2 = time.perf_counter()
    report_stage(progress, "writing", 0.9)
    summary = write_result(spec["out_dir"], image, input_id=spec.get("input_id", ""),
                           extra={"points_used": int(inp["alines"].shape[0]) if "alines" in inp else None})
    t3 = time.perf_counter()
    summary["timings"] = {"load_s": t1 - t0, "reconstruct_s": t2 - t1, "write_s": t3 - t2}
    if "alines" in inp:
        summary["points_used"] = int(inp["alines"].shape[0])
    return summary


def warm_up() -> int:
    """Import the heavy modules in a fresh worker (called once per pool process)."""
    import h5py  # noqa: F401

    from service import recon  # noqa: F401
    return os.getpid()
