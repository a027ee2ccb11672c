"""Unmixing result file (``unmix.h5``, ``format`` ``fpscan-unmix/1``; written with its
sO2 picture by :func:`service.spectral.write_unmix`): the maps ``hbo2``, ``hb``, ``thb``,
``so2`` and ``mask`` ``(n_z, n_y, n_x)``/``(n_z, n_x)``, the coordinates ``z``, ``y``,
``x`` (m) and ``wavelengths_m`` → a dict. An output, not data to reconstruct.
"""
from __future__ import annotations

import json
import os
from typing import Any

from service.formats._registry import Format, Source

__all__ = ["FORMAT", "UNMIX_FORMAT", "sniff", "load", "read_unmix"]

UNMIX_FORMAT = "fpscan-unmix/1"


def sniff(source: Source) -> bool:
    """True for an HDF5 file whose ``format`` attribute is ``fpscan-unmix/<version>``."""
    return source.attr("format").startswith("fpscan-unmix/")


def load(source: Source, **_: Any) -> dict:
    """The arrays and attributes as a dict (``mask`` bool, ``params`` dict, ``y`` None in
    2-D). Raises ValueError for another file."""
    f = source.h5
    if source.attr("format") != UNMIX_FORMAT:
        raise ValueError(f"{source.path} is not an {UNMIX_FORMAT} file")
    out = {k: f[k][...] for k in ("hbo2", "hb", "thb", "so2", "mask", "z", "x", "wavelengths_m")}
    out["y"] = f["y"][...] if "y" in f else None
    out["mask"] = out["mask"].astype(bool)
    out["params"] = json.loads(f.attrs["params"])
    out["input_id"] = str(f.attrs["input_id"])
    return out


def read_unmix(path: str | os.PathLike) -> dict:
    """Read an ``unmix.h5`` (through the registry: opened once, checked); raises
    ``ValueError`` for another file, FileNotFoundError."""
    from service.formats._registry import load as load_as

    return load_as(path, "unmix")[1]


FORMAT = Format(name="unmix", title="fpscan unmixing result (unmix.h5)", container="hdf5", sniff=sniff,
                load=load, order=40, noun="an unmixing result",
                refuse="this is an unmixing result (sO2 and THb maps), not data to reconstruct: open it with h5py")
