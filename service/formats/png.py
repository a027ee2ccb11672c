"""PNG picture (the MIPs and slices fpscan draws): recognised so that it is named when
given as data (not data to reconstruct) → its bytes.
"""
from __future__ import annotations

from typing import Any

from fpscan.service.formats.registry import Format, Source

__all__ = ["FORMAT", "sniff", "load"]


def sniff(source: Source) -> bool:
    """True for a file with the PNG signature.

    Parameters
    ----------
    source : Source
        The opened file (:class:`fpscan.service.formats.Source`).

    Returns
    -------
    bool
        Whether this format reads it.
    """
    return source.head.startswith(b"\x89PNG")


def load(source: Source, **_: Any) -> bytes:
    """The file's bytes.

    Parameters
    ----------
    source : Source
        The opened file (``source.fh``).
    **_
        Loading options, ignored.

    Returns
    -------
    bytes
        The whole file.
    """
    assert source.fh is not None
    return source.fh.read()


FORMAT = Format(rank=100, name="png", title="PNG picture", container="file", sniff=sniff, load=load, order=30,
                noun="a PNG picture", refuse="this is a PNG picture, not data to reconstruct")
