"""Dataset upload: ``POST /api/datasets`` (multipart ``file`` + ``format`` + spacings).

Formats:
- ``npy``: a NumPy array in k-Wave layout, ``(n_t, n_x)`` or ``(n_t, n_y, n_x)`` (time
  first, as k-Wave's ``'ty'``/``'tyz'``), with form fields ``dt`` (s), ``dx`` (m),
  optional ``dy`` (m, default dx) and ``c`` (m/s, default 1500). Loaded with
  ``allow_pickle=False``.
- ``kwave-hdf5``: an HDF5 file holding such an array at ``key`` (default
  ``sensor_data/clean``, then ``sensor_data``); spacings from the form or from the file's
  ``dt_s``, ``dx_m``, ``dy_m``, ``c_m_per_s`` attributes (shared/data/README.md layout).
- ``fpscan``: our scan file (``driver.scanfile``), reconstructed from its completed points.
- ``ipasc``: an IPASC HDF5 file (``service.ipasc.read_ipasc``).

The upload is stored under a server-chosen id (``<data_dir>/datasets/<id>/``); the client's
file name is never used as a path. Grid and point data are converted to the canonical
dataset file read by :mod:`service.jobs.work`.
"""
from __future__ import annotations

import math
import shutil
import uuid
from pathlib import Path

import numpy as np
from fastapi import APIRouter, Depends, File, Form, HTTPException, UploadFile

from service.api.context import Context, ctx, require_token
from service.api.models import Dataset, DatasetFormat

router = APIRouter(prefix="/api/datasets", tags=["datasets"])

MAX_SAMPLES = 2**31  # elements of one dataset array
HDF5_KEY_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-/.")


def _positive(name: str, value: float | None, *, required: bool = True) -> float | None:
    if value is None:
        if required:
            raise ValueError(f"{name} is required for this format")
        return None
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number")
    return float(value)


def _check_grid_array(a: np.ndarray) -> np.ndarray:
    if a.dtype.kind not in "iuf":
        raise ValueError(f"array must be real numbers, got dtype {a.dtype}")
    if a.ndim not in (2, 3):
        raise ValueError(f"array must be (n_t, n_x) or (n_t, n_y, n_x), got shape {list(a.shape)}")
    if min(a.shape) < 2:
        raise ValueError(f"every axis needs at least 2 samples, got shape {list(a.shape)}")
    if a.size > MAX_SAMPLES:
        raise ValueError("array too large")
    a = np.asarray(a, dtype=np.float32 if a.dtype.itemsize <= 4 else np.float64)
    if not np.all(np.isfinite(a)):
        raise ValueError("array contains NaN or infinite values")
    return a


def write_grid_dataset(path: Path, data: np.ndarray, *, dt: float, dx: float, dy: float | None, c: float) -> None:
    """The canonical grid dataset file (see :mod:`service.jobs.work`)."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["layout"] = "grid"
        f.create_dataset("data", data=data)
        f.attrs.update({"dt": dt, "dx": dx, "c": c})
        if dy is not None and data.ndim == 3:
            f.attrs["dy"] = dy


def write_points_dataset(path: Path, *, alines, positions, weights, dt: float, c: float, grid) -> None:
    """The canonical point dataset file (see :mod:`service.jobs.work`)."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["layout"] = "points"
        f.create_dataset("alines", data=np.asarray(alines))
        f.create_dataset("positions", data=np.asarray(positions, dtype=np.float64))
        if weights is not None:
            f.create_dataset("weights", data=np.asarray(weights, dtype=np.float64))
        f.create_dataset("grid_x", data=np.asarray(grid[0], dtype=np.float64))
        if len(grid) > 1:
            f.create_dataset("grid_y", data=np.asarray(grid[1], dtype=np.float64))
        f.attrs.update({"dt": dt, "c": c})


def _read_kwave_hdf5(src: Path, key: str | None):
    import h5py

    try:
        f = h5py.File(src, "r")
    except OSError:
        raise ValueError("file is not a readable HDF5 file") from None
    with f:
        keys = [key] if key else ["sensor_data/clean", "sensor_data"]
        for k in keys:
            if k in f and isinstance(f[k], h5py.Dataset):
                ds = f[k]
                if ds.size > MAX_SAMPLES:
                    raise ValueError("array too large")
                attrs = {a: f.attrs[a] for a in ("dt_s", "dx_m", "dy_m", "c_m_per_s") if a in f.attrs}
                return ds[...], attrs
    raise ValueError(f"no dataset {' or '.join(repr(k) for k in keys)} in the HDF5 file")


def import_dataset(src: Path, dest_dir: Path, fmt: str, *, dt, dx, dy, c, key) -> dict:
    """Validate and convert an uploaded file; returns the dataset's metadata (stored in
    the job store). Raises ``ValueError`` with the reason."""
    if fmt == "npy":
        try:
            a = np.load(src, allow_pickle=False, mmap_mode="r")
        except (ValueError, OSError, EOFError):
            raise ValueError("file is not a NumPy .npy array (pickles are refused)") from None
        if not isinstance(a, np.ndarray):
            raise ValueError("file is not a single NumPy array")
        data = _check_grid_array(np.asarray(a))
        dt, dx = _positive("dt", dt), _positive("dx", dx)
        dy = _positive("dy", dy, required=False)
        c = _positive("c", c, required=False) or 1500.0
        write_grid_dataset(dest_dir / "dataset.h5", data, dt=dt, dx=dx, dy=dy, c=c)
        return {"layout": "grid", "shape": list(data.shape), "dt": dt, "path": "dataset.h5"}
    if fmt == "kwave-hdf5":
        if key is not None and (not key or len(key) > 200 or not set(key) <= HDF5_KEY_CHARS):
            raise ValueError("key must be an HDF5 dataset path of [A-Za-z0-9_-/.]")
        raw, attrs = _read_kwave_hdf5(src, key)
        data = _check_grid_array(raw)
        dt = _positive("dt", dt if dt is not None else (float(attrs["dt_s"]) if "dt_s" in attrs else None))
        dx = _positive("dx", dx if dx is not None else (float(attrs["dx_m"]) if "dx_m" in attrs else None))
        dy = _positive("dy", dy if dy is not None else (float(attrs["dy_m"]) if "dy_m" in attrs else None),
                       required=False)
        c = _positive("c", c if c is not None else (float(attrs["c_m_per_s"]) if "c_m_per_s" in attrs else None),
                      required=False) or 1500.0
        write_grid_dataset(dest_dir / "dataset.h5", data, dt=dt, dx=dx, dy=dy, c=c)
        return {"layout": "grid", "shape": list(data.shape), "dt": dt, "path": "dataset.h5"}
    if fmt == "fpscan":
        from service.jobs.work import load_scan_points

        target = dest_dir / "scan.h5"
        shutil.copyfile(src, target)
        try:
            pts = load_scan_points(target)
        except (KeyError, OSError, TypeError, IndexError):
            raise ValueError("file is not a readable fpscan scan file") from None
        n_y, n_x = pts["lattice_shape"]
        return {"layout": "scan", "shape": [int(pts["alines"].shape[0]), int(pts["alines"].shape[1])],
                "dt": pts["dt"], "path": "scan.h5", "n_x": n_x, "n_y": n_y}
    if fmt == "ipasc":
        from service.ipasc import read_ipasc

        try:
            pts = read_ipasc(src)
        except (KeyError, OSError, TypeError, IndexError):
            raise ValueError("file is not a readable IPASC HDF5 file") from None
        write_points_dataset(dest_dir / "dataset.h5", alines=pts["alines"], positions=pts["positions"],
                             weights=pts.get("weights"), dt=pts["dt"], c=float(c or pts["c"]), grid=pts["grid"])
        return {"layout": "points", "shape": list(pts["alines"].shape), "dt": pts["dt"], "path": "dataset.h5"}
    raise ValueError(f"unknown format {fmt!r}")


@router.post("", status_code=201, response_model=Dataset, dependencies=[Depends(require_token)],
             responses={413: {"description": "upload larger than the configured limit"}})
def upload_dataset(file: UploadFile = File(..., description="the data file"),
                   format: DatasetFormat = Form(...),
                   dt: float | None = Form(None, description="sample interval, s"),
                   dx: float | None = Form(None, description="lateral spacing along x, m"),
                   dy: float | None = Form(None, description="lateral spacing along y, m"),
                   c: float | None = Form(None, description="speed of sound, m/s"),
                   key: str | None = Form(None, max_length=200, description="HDF5 dataset path (kwave-hdf5)"),
                   cx: Context = Depends(ctx)) -> Dataset:
    """Upload a dataset for reconstruction → 201 ``{dataset_id, ...}``."""
    dataset_id = uuid.uuid4().hex
    dest = Path(cx.settings.data_dir) / "datasets" / dataset_id
    dest.mkdir(parents=True)
    src = dest / "upload.bin"
    limit = cx.settings.upload_limit
    size = 0
    try:
        with open(src, "wb") as out:
            while chunk := file.file.read(1 << 20):
                size += len(chunk)
                if size > limit:
                    raise HTTPException(413, f"upload larger than the limit of {limit} bytes")
                out.write(chunk)
        try:
            meta = import_dataset(src, dest, format, dt=dt, dx=dx, dy=dy, c=c, key=key)
        except ValueError as exc:
            raise HTTPException(422, str(exc)) from None
    except BaseException:
        shutil.rmtree(dest, ignore_errors=True)
        raise
    src.unlink(missing_ok=True)
    meta["format"] = format
    cx.store.put_dataset(dataset_id, meta)
    return Dataset(dataset_id=dataset_id, format=format, layout=meta["layout"], shape=meta["shape"], dt=meta["dt"])
