"""Dense datasets for the experiments: data on a regular sensor grid plus its sampling.

A dense dataset is what the paper's experiments start from (§6: the full 1024-point
line; §7: the 226 × 226 scan): A-lines on every lattice point, from which sensor masks
pick their points. Built-in phantoms are simulated with the exact planar forward model
(:func:`service.recon.forward_grid`); ``load_dense`` reads an HDF5 file such as the
k-Wave reference data (``sensor_data/clean`` with ``axes`` "t, y" or "t, y, z";
attributes ``dt_s``, ``dx_m``/``dy_m``/``dz_m``, ``c_m_per_s``, see ``data/README.md``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class DenseDataset:
    """Sensor data on a full regular lattice.

    Attributes
    ----------
    data : ndarray ``(n_t, n_x)`` (2-D, line sensor) or ``(n_t, n_y, n_x)`` (3-D), Pa.
    dx : lateral pitch in m (same in x and y).
    dt : sample interval in s (t_n = n·dt).
    c : sound speed in m/s.
    p0 : optional ground truth ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` with depth spacing
        ``dz`` (m), row 0 at the sensor plane.
    source : where it came from (file path or phantom name).
    """

    data: np.ndarray
    dx: float
    dt: float
    c: float = 1500.0
    p0: np.ndarray | None = None
    dz: float | None = None
    source: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def ndim(self) -> int:
        """2 for a line sensor, 3 for a planar sensor."""
        return self.data.ndim

    @property
    def n_t(self) -> int:
        return self.data.shape[0]

    @property
    def lateral_shape(self) -> tuple[int, ...]:
        """``(n_x,)`` or ``(n_y, n_x)``."""
        return self.data.shape[1:]

    def crop(self, *, n_t: int | None = None, lateral: int | None = None) -> DenseDataset:
        """A copy keeping the first ``n_t`` samples and the central ``lateral`` points
        per lateral axis (the ground truth is cropped laterally to match)."""
        data, p0 = self.data, self.p0
        if n_t is not None:
            data = data[: max(2, int(n_t))]
        if lateral is not None:
            sl = []
            for n in data.shape[1:]:
                m = min(n, int(lateral))
                lo = (n - m) // 2
                sl.append(slice(lo, lo + m))
            data = data[(slice(None), *sl)]
            if p0 is not None:
                p0 = p0[(slice(None), *sl)]
        return DenseDataset(np.ascontiguousarray(data), self.dx, self.dt, self.c, p0, self.dz, self.source, dict(self.meta))


def _attr(attrs, *names, default=None):
    for n in names:
        if n in attrs:
            return float(np.asarray(attrs[n]).ravel()[0])
    return default


def load_dense(path: str | Path) -> DenseDataset:  # noqa: C901 -- one dataset loader (helper "pipeline")
    """Read a dense dataset from HDF5: the k-Wave reference files' layout, or an fpscan
    scan file covering its whole lattice (see :func:`load_dense_scan`).

    The file must hold ``sensor_data/clean`` (or a dataset ``sensor_data``) shaped
    ``(n_t, n_lateral)`` or ``(n_t, n_y, n_x)`` and the attributes ``dt_s`` and the
    lateral spacing: k-Wave files (depth is k-Wave's x) use ``dy_m`` (and ``dz_m``, which
    must equal it); other files ``dx_m``. ``c_m_per_s`` defaults to 1500. A ``p0``
    dataset, if present, is kept as ground truth (its depth spacing from its
    ``spacing_m`` attribute).

    Raises
    ------
    ValueError
        Missing file, datasets or attributes, wrong dimensions, unequal lateral spacing.
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"data file not found: {path}")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path} is not a readable HDF5 file: {exc}") from exc
    with f:
        fmt = f.attrs.get("format")
        if isinstance(fmt, bytes):
            fmt = fmt.decode()
        if isinstance(fmt, str) and fmt.startswith("fpscan-scan/"):
            f.close()
            return load_dense_scan(path)
        if "sensor_data/clean" in f:
            ds = f["sensor_data/clean"]
        elif "sensor_data" in f and isinstance(f["sensor_data"], h5py.Dataset):
            ds = f["sensor_data"]
        else:
            raise ValueError(f"{path}: no 'sensor_data/clean' (or 'sensor_data') dataset")
        data = np.asarray(ds[...], dtype=np.float64)
        attrs = dict(f.attrs)
        if data.ndim not in (2, 3):
            raise ValueError(f"{path}: sensor data must be (n_t, n_x) or (n_t, n_y, n_x), got {data.shape}")
        dt = _attr(attrs, "dt_s")
        if dt is None or not dt > 0:
            raise ValueError(f"{path}: missing or invalid attribute dt_s")
        kwave = "kwave_commit" in attrs or "kwave_DataOrder" in ds.attrs
        if kwave:
            dx = _attr(attrs, "dy_m", "dx_m")
            if data.ndim == 3:
                dz_lat = _attr(attrs, "dz_m", default=dx)
                if not np.isclose(dz_lat, dx, rtol=1e-9):
                    raise ValueError(f"{path}: lateral spacings differ ({dx} m vs {dz_lat} m); need a square lattice")
        else:
            dx = _attr(attrs, "dx_m", "dy_m")
        if dx is None or not dx > 0:
            raise ValueError(f"{path}: missing or invalid lateral spacing attribute (dx_m / dy_m)")
        c = _attr(attrs, "c_m_per_s", default=1500.0)
        p0 = dz = None
        if "p0" in f and isinstance(f["p0"], h5py.Dataset):
            p0 = np.asarray(f["p0"][...], dtype=np.float64)
            spacing = f["p0"].attrs.get("spacing_m")
            dz = float(np.asarray(spacing).ravel()[0]) if spacing is not None else dx
            if p0.ndim != data.ndim or p0.shape[1:] != data.shape[1:]:
                p0 = dz = None
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{path}: sensor data contains NaN or inf")
    return DenseDataset(data, dx, dt, c, p0, dz, Path(path).name, {"kwave": kwave})


def load_dense_scan(path: str | Path) -> DenseDataset:
    """A dense dataset from an fpscan scan file (``driver.scanfile``) whose plan covers
    every point of its lattice (e.g. a full-lattice scan, or a replayed dense dataset).

    The DC-normalised pressure of point k goes to its lattice index (i_x, i_y); the data
    are ``(n_t, n_y, n_x)`` (``(n_t, n_x)`` for a line lattice), ``dx`` the lattice pitch,
    ``dt`` and ``c`` from the plan's acquisition settings.

    Raises ValueError if the plan does not cover the whole lattice or a point is not
    complete (a sparse scan is reconstructed with ``fpscan recon``, not evaluated here).
    """
    from driver.scanfile import read_scan

    sd = read_scan(path)
    lat = sd.plan.get("lattice", {})
    try:
        n_x, n_y, pitch = int(lat["n_x"]), int(lat["n_y"]), float(lat["pitch"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: the plan has no valid lattice") from exc
    idx = np.asarray(sd.indices, dtype=np.int64).reshape(-1, 2)
    covered = np.zeros((n_y, n_x), dtype=bool)
    covered[idx[:, 1], idx[:, 0]] = True
    if not covered.all():
        raise ValueError(f"{path}: not a dense scan — its plan covers {int(covered.sum())} of the "
                         f"{n_x * n_y} lattice points")
    if not np.all(sd.completed):
        raise ValueError(f"{path}: {int((~sd.completed).sum())} of {sd.n_points} points are not complete")
    data = np.empty((sd.n_t, n_y, n_x))
    data[:, idx[:, 1], idx[:, 0]] = np.asarray(sd.pressure, dtype=np.float64).T
    if n_y == 1:
        data = data[:, 0, :]
    return DenseDataset(data, pitch, float(sd.dt), float(sd.sound_speed), None, None, Path(path).name,
                        {"scan_plan_id": sd.plan_id})


def add_noise(data: np.ndarray, snr_db: float | None, seed: int = 0) -> np.ndarray:
    """White Gaussian noise at ``snr_db`` dB below the data's mean power (paper §6: 30 dB).

    ``sigma = rms(data) / 10^(snr_db/20)``; ``None`` returns the data unchanged.
    Raises ValueError for a non-finite SNR.
    """
    if snr_db is None:
        return data
    if not np.isfinite(snr_db):
        raise ValueError(f"snr_db must be finite, got {snr_db}")
    rms = float(np.sqrt(np.mean(np.square(data))))
    rng = np.random.default_rng(seed)
    return data + rng.standard_normal(data.shape) * rms / 10 ** (snr_db / 20)
