"""Dense datasets for the experiments: data on a regular sensor grid plus its sampling.

A dense dataset is what the paper's experiments start from (§6: the full 1024-point
line; §7: the 226 × 226 scan): A-lines on every lattice point, from which sensor masks
pick their points. It is the grid dataset of :mod:`fpscan.service.storage.loader` with an
optional ground truth. Built-in phantoms are simulated with the exact planar forward
model (:func:`fpscan.service.recon.forward_grid`); ``load_dense`` reads a file with
:func:`fpscan.service.storage.loader.load_dataset`: the k-Wave reference data
(``sensor_data/clean`` with ``axes`` "t, y" or "t, y, z"; attributes ``dt_s``,
``dx_m``/``dy_m``/``dz_m``, ``c_m_per_s``, see ``data/README.md``) or a full-lattice scan.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fpscan.service import formats
from fpscan.service.recon.dataset import GridDataset, PointDataset
from fpscan.service.storage.loader import input_formats

__all__ = ["DenseDataset", "load_dense", "add_noise"]


@dataclass
class DenseDataset(GridDataset):
    """Sensor data on a full regular lattice with an optional ground truth.

    A :class:`GridDataset` (its fields: ``data``, ``dx``, ``dt``, ``sound_speed``, ``dy``, ``t0``,
    ``source``, ``meta``, ``wavelengths``) plus the ground truth the experiments score
    against.

    Attributes
    ----------
    data : ndarray
        Pressure in Pa, ``(n_t, n_x)`` (2-D, line sensor) or ``(n_t, n_y, n_x)`` (3-D), time
        first.
    dx : float
        Lateral pitch, m (the same in x and y).
    dt : float
        Sample interval, s (t_n = n·dt).
    sound_speed : float
        Sound speed, m/s.
    dy : float or None
        The y pitch, m, where the dataset records one.
    source : str
        Where the data came from (a file name or a simulation's name).
    meta : dict
        Other facts about the data (e.g. ``kwave``, ``scan_plan_id``, ``snr_db``).
    p0 : ndarray or None
        Ground-truth initial pressure ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, row 0 at the sensor
        plane; None without one.
    dz : float or None
        The ground truth's depth spacing, m.
    """

    p0: np.ndarray | None = None
    dz: float | None = None

    @property
    def n_t(self) -> int:
        """Samples per A-line."""
        return self.data.shape[0]

    def depth_rows(self, minimum: int) -> int:
        """Output depth rows at spacing ``c·dt`` (the experiments' depth grid, asked for as ``dz``) that
        cover the ground truth's depth (``p0`` rows × ``dz``), or half the samples without
        a ground truth; at least ``minimum`` and at most ``n_t``."""
        if self.p0 is not None and self.dz:
            n_z = round(self.p0.shape[0] * self.dz / (self.sound_speed * self.dt))
        else:
            n_z = self.n_t // 2
        return max(int(minimum), min(n_z, self.n_t))

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
        return DenseDataset(data=np.ascontiguousarray(data), dx=self.dx, dt=self.dt, sound_speed=self.sound_speed, dy=self.dy,
                            source=self.source, meta=dict(self.meta), p0=p0, dz=self.dz)


def load_dense(path: str | Path, key: str | None = None) -> DenseDataset:
    """Read a dense dataset through the registry of formats (:func:`fpscan.service.formats.load`).

    The k-Wave reference files' layout (or any HDF5 array in k-Wave layout), or an fpscan scan
    file covering its whole lattice. The data must be ``(n_t, n_lateral)`` or
    ``(n_t, n_y, n_x)`` with ``dt_s`` and the lateral spacing in the file; the two lateral
    spacings must be equal (square lattice). ``c_m_per_s`` defaults to 1500. A ``p0``
    dataset, if present, is kept as ground truth (its depth spacing from its ``spacing_m``
    attribute). Data are float64.

    Parameters
    ----------
    path : str or pathlib.Path
        The data file.
    key : str, optional
        The HDF5 dataset holding the sensor data (e.g. ``sensor_data/noisy30dB``; default
        ``sensor_data/clean`` or the file's only 2-/3-D dataset).

    Returns
    -------
    DenseDataset
        The data (float64), with ``source`` the file's name and the ground truth where the file
        holds one.

    Raises
    ------
    ValueError
        Missing file, datasets or attributes, wrong dimensions, unequal lateral spacing,
        a scan that does not cover its whole lattice.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"data file not found: {path}")
    try:
        # a scan with no completed point is still judged by its plan's coverage below
        loaded = formats.load(path, choices=input_formats(), key=key, allow_empty=True, ground_truth=True)[1]
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    if isinstance(loaded, PointDataset):
        try:
            ds = loaded.to_grid()
        except ValueError as exc:
            raise ValueError(f"{path}: not a dense scan — {exc}") from None
    else:
        ds = loaded
    if ds.data.ndim == 3 and ds.dy is not None and not np.isclose(ds.dy, ds.dx, rtol=1e-9):
        raise ValueError(f"{path}: lateral spacings differ ({ds.dx} m vs {ds.dy} m); need a square lattice")
    p0, dz = ds.meta.get("p0"), ds.meta.get("p0_dz")  # the k-Wave files' ground truth (read with the data)
    meta: dict = {"kwave": bool(ds.meta.get("kwave_naming", False))}
    if ds.source == "fpscan":
        meta = {"scan_plan_id": ds.meta.get("plan_id")}
    return DenseDataset(data=np.asarray(ds.data, dtype=np.float64), dx=ds.dx, dt=ds.dt, sound_speed=ds.sound_speed,
                        dy=ds.dy, source=path.name, meta=meta, p0=p0, dz=dz)


def add_noise(data: np.ndarray, snr_db: float | None, seed: int = 0, reference: str = "rms") -> np.ndarray:
    """White Gaussian noise at ``snr_db`` dB below the data's mean power (paper §6: 30 dB), or
    below its peak.

    ``sigma = rms(data) / 10^(snr_db/20)`` (``reference="rms"``), or ``sigma = max|data| /
    10^(snr_db/20)`` (``reference="peak"``: k-Wave's ``addNoise(signal, snr, 'peak')``, usual for
    impulsive signals, whose RMS is far below their peak).

    Parameters
    ----------
    data : ndarray
        The clean data, any shape (Pa).
    snr_db : float or None
        Signal-to-noise ratio in dB; None returns ``data`` unchanged (the same object).
    seed : int, optional
        Seed of the noise (``numpy.random.default_rng``).
    reference : {"rms", "peak"}, optional
        What the SNR is relative to (default the RMS).

    Returns
    -------
    ndarray
        ``data`` plus the noise, a new array of the same shape.

    Raises
    ------
    ValueError
        A non-finite SNR, an unknown ``reference``.

    References
    ----------
    .. [1] k-Wave's ``addNoise`` (B. Treeby, B. Cox, J. Biomed. Opt. 15 (2010) 021314).
    """
    if snr_db is None:
        return data
    if not np.isfinite(snr_db):
        raise ValueError(f"snr_db must be finite, got {snr_db}")
    if reference not in ("rms", "peak"):
        raise ValueError(f"reference must be 'rms' or 'peak', got {reference!r}")
    level = float(np.max(np.abs(data))) if reference == "peak" else float(np.sqrt(np.mean(np.square(data))))
    rng = np.random.default_rng(seed)
    return data + rng.standard_normal(data.shape) * level / 10 ** (snr_db / 20)
