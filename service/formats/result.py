"""Reconstruction result file (``volume.h5``, ``format`` ``fpscan-result/1``; layout:
:mod:`service.storage.results`, which writes it with the MIPs, and docs/file-formats.md):
the p0 volume ``/p0`` ``(n_z, n_y, n_x)`` or ``(n_z, n_x)`` with its coordinates ``/z``,
``/y``, ``/x`` (m) → :class:`ResultVolume`. An output, not data to reconstruct.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.formats._registry import Format, Source

__all__ = ["FORMAT", "RESULT_FORMAT", "ResultVolume", "sniff", "load", "read_result", "read_slice"]

RESULT_FORMAT = "fpscan-result/1"


@dataclass
class ResultVolume:
    """A result file's content. ``p0`` ``(n_z, n_y, n_x)``/``(n_z, n_x)``; ``z``, ``x``
    (and ``y``, None in 2-D) coordinate vectors in m; ``method``; ``params`` dict;
    ``input_id``; ``attrs`` (all root attributes)."""

    p0: np.ndarray
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray | None
    method: str
    params: dict
    input_id: str
    attrs: dict = field(default_factory=dict)

    @property
    def ndim(self) -> int:
        return self.p0.ndim

    @property
    def p0_unit(self) -> str:
        """``"Pa"`` (calibrated scan) or ``"a.u."`` (files before the attribute: a.u.)."""
        return "Pa" if self.attrs.get("p0_unit") == "Pa" else "a.u."


def sniff(source: Source) -> bool:
    """True for an HDF5 file whose ``format`` attribute is ``fpscan-result/<version>``."""
    return source.attr("format").startswith("fpscan-result/")


def load(source: Source, **_: Any) -> ResultVolume:
    """The result file's volume, coordinates and attributes. Raises ValueError (not a
    result file)."""
    f = source.h5
    attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    if attrs.get("format") != RESULT_FORMAT:
        raise ValueError(f"{source.path} is not an {RESULT_FORMAT} file")
    p0 = f["p0"][()]
    z, x = f["z"][()], f["x"][()]
    y = f["y"][()] if "y" in f else None
    return ResultVolume(p0=p0, z=z, x=x, y=y, method=str(attrs["method"]),
                        params=json.loads(attrs["params"]), input_id=str(attrs["input_id"]),
                        attrs=attrs)


def read_result(path: str | os.PathLike) -> ResultVolume:
    """Read a result file (through the registry: opened once, checked). Raises
    FileNotFoundError, ValueError (not a result file)."""
    from service.formats._registry import load as load_as

    return load_as(path, "result")[1]


def read_slice(path: str | os.PathLike, index: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The depth slice ``index`` of a result file's p0 — ``(n_y, n_x)``, or the image row
    ``(n_x,)`` of a 2-D result — with ``z``, ``x``, ``y`` (None in 2-D), read without
    loading the whole volume. Raises ValueError (index not an integer in range, not a
    result file), FileNotFoundError."""
    from service.formats._registry import open_source

    with open_source(path, "hdf5", name="result") as src:
        f = src.h5
        if "p0" not in f or "z" not in f or "x" not in f:
            raise ValueError(f"{src.path} is not an {RESULT_FORMAT} file")
        ds = f["p0"]
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) \
                or not 0 <= index < ds.shape[0]:
            raise ValueError(f"index must be an integer in [0, {ds.shape[0]}) (depth samples)")
        img = ds[index]
        z, x = f["z"][()], f["x"][()]
        y = f["y"][()] if "y" in f else None
    return img, z, x, y


FORMAT = Format(name="result", title="fpscan reconstruction result (volume.h5)", container="hdf5",
                sniff=sniff, load=load, order=30, noun="a reconstruction result",
                refuse="this is a reconstruction result (a p0 volume), not data to reconstruct: open it with "
                       "h5py, or `fpscan export` it to OME-TIFF for ImageJ/napari")
