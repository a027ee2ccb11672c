"""Unmixing result file (``unmix.h5``, ``format`` ``fpscan-unmix/1``; written by
:func:`write`, with its sO2 picture by :func:`fpscan.service.spectral.write_unmix`): the maps ``hbo2``, ``hb``, ``thb``,
``so2`` and ``mask`` ``(n_z, n_y, n_x)``/``(n_z, n_x)``, the coordinates ``z``, ``y``,
``x`` (m) and ``wavelengths_m`` → a dict. An output, not data to reconstruct. Its
parameters name the speed of sound ``sound_speed`` (:mod:`fpscan.service.names`), as the result
volume's do; a file an older fpscan wrote with ``c`` reads the same.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fpscan.service.disk import file_replaced
from fpscan.service.formats.registry import Format, Source
from fpscan.service.names import current_names

if TYPE_CHECKING:
    import numpy.typing as npt

    from fpscan.service.recon.unmix import Unmixed

__all__ = ["FORMAT", "UNMIX_FORMAT", "sniff", "load", "write", "read_unmix"]

UNMIX_FORMAT = "fpscan-unmix/1"


def sniff(source: Source) -> bool:
    """True for an HDF5 file whose ``format`` attribute is ``fpscan-unmix/<version>``.

    Parameters
    ----------
    source : Source
        The opened HDF5 file (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    return source.attr("format").startswith("fpscan-unmix/")


def load(source: Source, **_: Any) -> dict:
    """The unmixing result's arrays and attributes as a dict.

    Parameters
    ----------
    source : Source
        The opened HDF5 file.
    **_
        Loading options, ignored.

    Returns
    -------
    dict
        ``hbo2``, ``hb``, ``thb``, ``so2`` ``(n_z, [n_y,] n_x)``, ``mask`` (bool), ``z``, ``x``,
        ``y`` (m; None in 2-D), ``wavelengths_m``, ``params`` (dict with ``sound_speed``, also
        where an older file says ``c``) and ``input_id``.

    Raises
    ------
    ValueError
        A file whose ``format`` is not ``fpscan-unmix/1``.
    """
    f = source.h5
    if source.attr("format") != UNMIX_FORMAT:
        raise ValueError(f"{source.path} is not an {UNMIX_FORMAT} file")
    out = {k: f[k][...] for k in ("hbo2", "hb", "thb", "so2", "mask", "z", "x", "wavelengths_m")}
    out["y"] = f["y"][...] if "y" in f else None
    out["mask"] = out["mask"].astype(bool)
    out["params"] = current_names(json.loads(f.attrs["params"]))
    out["input_id"] = str(f.attrs["input_id"])
    return out


def write(path: str | os.PathLike, u: Unmixed, z: npt.ArrayLike, x: npt.ArrayLike, y: npt.ArrayLike | None = None,
          *, input_id: str = "", extra: dict | None = None) -> Path:
    """Write an unmixing result as ``path`` (via a temporary sibling, renamed).

    ``extra`` is recorded beside ``u.params``; the speed of sound is stored as ``sound_speed``
    (an earlier release's ``c`` too: :func:`fpscan.service.names.current_names`).

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (``unmix.h5``).
    u : Unmixed
        A ``fpscan.service.recon.unmix.Unmixed``: maps ``(n_z, [n_y,] n_x)``, mask, wavelengths (m),
        params.
    z, x : array_like
        The depth and x coordinates, m.
    y : array_like, optional
        The y coordinates, m; None in 2-D.
    input_id : str, optional
        The input's id (attribute ``input_id``).
    extra : dict, optional
        More parameters to record.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ValueError
        Parameters that JSON cannot hold, before anything is written.
    """
    import h5py
    import numpy as np

    from fpscan.service.formats.result import params_json

    path = Path(path)
    # the result files' one canonical parameter JSON (ValueError before anything is written)
    params = params_json(current_names({**u.params, **(extra or {})}))
    with file_replaced(path) as tmp, h5py.File(tmp, "w") as f:  # a temporary sibling, removed on any error
        f.attrs["format"] = UNMIX_FORMAT
        f.attrs["params"] = params
        f.attrs["input_id"] = input_id
        f.attrs["concentration_units"] = str(u.params.get("concentration_units", ""))
        for name in ("hbo2", "hb", "thb", "so2"):
            f.create_dataset(name, data=getattr(u, name), compression="gzip", compression_opts=4)
        f.create_dataset("mask", data=u.mask.astype(np.uint8), compression="gzip", compression_opts=4)
        f.create_dataset("z", data=np.asarray(z, dtype=np.float64))
        f.create_dataset("x", data=np.asarray(x, dtype=np.float64))
        if y is not None:
            f.create_dataset("y", data=np.asarray(y, dtype=np.float64))
        f.create_dataset("wavelengths_m", data=u.wavelengths)
    return path


def read_unmix(path: str | os.PathLike) -> dict:
    """Read an ``unmix.h5`` (through the registry: opened once, checked).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        As :func:`load`.

    Raises
    ------
    ValueError
        Another file.
    FileNotFoundError
        No file at ``path``.
    """
    from fpscan.service.formats.registry import load as load_as

    return load_as(path, "unmix")[1]


FORMAT = Format(rank=80, name="unmix", title="fpscan unmixing result (unmix.h5)", container="hdf5", sniff=sniff,
                load=load, write=write, order=40, noun="an unmixing result",
                refuse="this is an unmixing result (sO2 and THb maps), not data to reconstruct: open it with h5py")
