"""HDF5 files from users, checked before anything is read: the one vetting step every HDF5
file fpscan opens from user input goes through (the registry of formats,
``fpscan.service.formats.open_source``; the simulator's replay and volume sources,
``fpscan.driver.sources``, through ``fpscan.driver.scanfile.open_checked``). Imports no HDF5 library until
a check runs.

HDF5 is a container that can point elsewhere and promise more than it holds. Before an
HDF5 file is imported, :func:`check_hdf5_file` walks every link and dataset *without reading
data* and refuses:

- external links (``h5py.ExternalLink``: would open another file of the server),
- datasets with HDF5 external storage (raw data in other files, e.g. ``/etc/passwd``),
- virtual datasets (their sources are other files),
- datasets whose declared sizes (shape × dtype) exceed ``max_bytes`` (the caller derives
  it from the upload and memory limits), one alone or all together, nested groups included and
  each link to a dataset counted (a reader that follows every link of a group, a MATLAB
  struct's fields, reads a dataset linked twice twice: a file of one 60 MB dataset linked
  20 times would decode 1.2 GB), and datasets without filters whose allocated
  storage is smaller than declared (unwritten chunks read as the fill value: a 1.5 kB
  file can declare gigabytes),
- chunked datasets, filtered (gzip, ...) or not, with chunks that were never written (they
  read as the fill value: a 1.5 kB gzip-filtered file declared 2 GiB), and a file whose
  datasets declare more than :data:`MAX_RATIO` times the bytes they store (every stored
  byte is earned: a decoded size is bounded by a ratio to the bytes actually stored,
  filters included).

The ratio bound: deflate (gzip) cannot exceed about 1032:1 even on constant data; real
float data reaches far less — the k-Wave reference files (gzip 6 + shuffle) store their
sensor data at 1.2-1.5:1 and p0 at 1.1:1, measured A-lines are noisy, and a float array
that is 99 % exact zeros compresses to about 100:1. So a file that declares more than
100× what it stores is padding or unwritten space, refused with the reason (a file that
really is mostly zeros can be uploaded without compression, paying its bytes). Datasets
of at most :data:`SMALL_BYTES` are not checked for unwritten chunks (index arrays compress
far beyond 100:1 and are small); they count towards the ratio with that slack.

"""
from __future__ import annotations

import os
from typing import Any

__all__ = ["HDF5_SIGNATURE", "SMALL_BYTES", "MAX_RATIO", "is_hdf5", "check_hdf5_file"]

#: the 8 bytes an HDF5 file starts with (its superblock at offset 0; HDF5 file format spec, "Format Signature")
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"

#: Datasets up to this many declared bytes are not checked for unwritten storage.
SMALL_BYTES = 1 << 20
#: Most decoded bytes a file's datasets may declare per byte they store (module docstring).
MAX_RATIO = 100
def is_hdf5(path: str | os.PathLike) -> bool:
    """True if the file starts with the HDF5 signature (superblock at offset 0).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool

    Raises
    ------
    OSError
        The file cannot be read.
    """
    with open(path, "rb") as fh:
        return fh.read(8) == HDF5_SIGNATURE


def check_hdf5_file(f: Any, *, max_bytes: int) -> None:
    """Refuse an HDF5 file already open (``h5py.File``, read-only) that points outside itself
    or declares more than it may hold (module docstring). Reads no data: the registry of
    formats (:mod:`fpscan.service.formats`) opens a file once and checks it here before any format
    reads it.

    Parameters
    ----------
    f : h5py.File
        Open read-only.
    max_bytes : int
        The most bytes the file's datasets may declare, any one and all together (each link
        to a dataset counted).

    Raises
    ------
    ValueError
        With the reason (the file's own object names only).
    """
    import h5py

    problems: list[str] = []
    sizes = [0, 0]  # declared, stored: bytes of every dataset

    def visit(name: str, link: Any) -> None:
        if problems:
            return
        if isinstance(link, h5py.ExternalLink):
            problems.append(f"{name!r} is an external link to another file (refused)")
            return
        if not isinstance(link, h5py.HardLink):
            return
        obj = f.get(name)
        if isinstance(obj, h5py.Dataset):
            problems.extend(_dataset_problems(name, obj, max_bytes, sizes)[:1])

    try:
        f.visititems_links(visit)
        if not problems:  # root attributes are read by every format; reading them is bounded
            dict(f.attrs)
    except (OSError, RuntimeError, KeyError) as exc:
        raise ValueError(f"HDF5 file is corrupt ({type(exc).__name__})") from None
    if problems:
        raise ValueError(problems[0])
    declared, stored = sizes
    if declared > max_bytes:
        raise ValueError(f"the file's datasets declare {declared} bytes together (every link counted), more than "
                         f"the limit of {max_bytes} bytes")
    if declared > MAX_RATIO * stored + SMALL_BYTES:
        raise ValueError(f"the file's datasets declare {declared} bytes but store {stored} (more than "
                         f"{MAX_RATIO}:1, beyond what real data compresses to; refused)")


def _dataset_problems(name: str, ds: Any, max_bytes: int, sizes: list[int]) -> list[str]:
    import numpy as np

    if ds.is_virtual:
        return [f"dataset {name!r} is a virtual dataset (refused)"]
    dcpl = ds.id.get_create_plist()
    if dcpl.get_external_count() > 0:
        return [f"dataset {name!r} uses HDF5 external storage in other files (refused)"]
    shape = ds.shape or ()
    declared = int(np.prod(shape, dtype=object)) * ds.dtype.itemsize if shape is not None else 0
    if declared > max_bytes:
        return [f"dataset {name!r} declares {declared} bytes {tuple(shape)}, more than the limit of "
                f"{max_bytes} bytes"]
    stored = int(ds.id.get_storage_size())
    sizes[0] += declared
    sizes[1] += stored
    if declared <= SMALL_BYTES:
        return []
    if dcpl.get_nfilters() == 0 and stored < declared:
        return [f"dataset {name!r} declares {declared} bytes but stores {stored} "
                "(unwritten data; refused)"]
    if ds.chunks is not None:
        expected = int(np.prod([-(-int(n) // int(c)) for n, c in zip(shape, ds.chunks)], dtype=object))
        written = int(ds.id.get_num_chunks())
        if written < expected:
            return [f"dataset {name!r} declares {declared} bytes but {expected - written} of its {expected} "
                    "chunks were never written (they would read as the fill value; refused)"]
    return []


