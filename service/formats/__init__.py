"""File formats: one module per format, one registry.

Each module declares one :class:`Format` — its ``sniff`` (cheap detection from the file's
first bytes and, for HDF5, its root attributes and links), its ``load`` (and ``write``
where it has one), whether it is a reconstruction input and an upload choice — and this
package registers it. The registry serves format detection (:func:`detect`), loading by
name or from the content (:func:`load`), the lists of choices (:func:`names`: the
reconstruction's ``--format``, ``POST /api/datasets``'s ``format``, ``GET
/api/datasets/formats`` for the web page and the HTTP client) and the one place a file is
opened and checked (:func:`open_source`: opened once, the hostile-HDF5 checks of
``service.formats.untrusted`` applied to every format).

=============  ==========  ==================================================  =====================
name           module      content                                             role
=============  ==========  ==================================================  =====================
``npy``        npy         NumPy array in k-Wave layout → GridDataset          input, upload
``fpscan``     scan        fpscan scan file → PointDataset                     input, upload
``dataset``    dataset     canonical dataset (``fpscan-dataset/1``)            input (server's own)
``result``     result      reconstruction result ``volume.h5`` → ResultVolume  output
``unmix``      unmix       unmixing result ``unmix.h5`` → dict                 output
``ipasc``      ipasc       IPASC HDF5 → PointDataset                           input, upload
``kwave-hdf5`` kwave_hdf5  HDF5 array in k-Wave layout → GridDataset           input, upload
``kwave-mat``  kwave_mat   k-Wave MAT-file (MAT v5, v7.3) → GridDataset         input, upload
``plan``       plan        plan JSON → plan dict                               refused as data
``png``        png         PNG picture → bytes                                 refused as data
``ome-tiff``   ome_tiff    p0 volume as OME-TIFF (from a result)               export
``ome-zarr``   ngff        p0 volume as OME-Zarr, NGFF 0.5 (from a result)     export (a folder)
=============  ==========  ==================================================  =====================

Exports: a format with ``export_from`` and ``export`` writes files of another (``result`` and
``fpscan`` export themselves, ``ipasc`` a scan file, ``ome-tiff`` / ``ome-zarr`` a result):
:func:`export_formats`, :func:`export_file` (the one dispatch of ``fpscan export``, ``GET
/api/jobs/{id}/export/{format}``, the HTTP client's ``export`` and the web page's downloads).

Adding a format: a module here with ``sniff``, ``load`` (and ``write``; its load options as a
typed model of ``service.formats.load_options``, ``Format.options``), or an ``export``, and a
``FORMAT = Format(...)``, and its test — nothing else: every public module of this
package that declares a ``FORMAT`` is registered when the package is imported (after the
built-in ones of :data:`BUILTIN`, in module-name order: :func:`_discover`), and the CLI
help, the API's choices, the web page and the HTTP client follow from the registry.
"""
from __future__ import annotations

import importlib
import pkgutil

from service.formats import (
    dataset,
    ipasc,
    kwave_hdf5,
    kwave_mat,
    ngff,
    npy,
    ome_tiff,
    plan,
    png,
    result,
    scan,
    unmix,
)
from service.formats._registry import (
    FORMATS,
    HEAD_BYTES,
    MAX_BYTES,
    Format,
    Source,
    describe,
    detect,
    export_file,
    export_formats,
    load,
    names,
    open_source,
    register,
    sniff,
    unregister,
)

__all__ = ["FORMATS", "BUILTIN", "HEAD_BYTES", "MAX_BYTES", "Format", "Source", "describe", "detect", "export_file",
           "export_formats", "load", "names", "open_source", "register", "sniff", "unregister", "upload_formats"]

#: the formats fpscan knows, in the order of the lists of choices
BUILTIN = (npy.FORMAT, kwave_hdf5.FORMAT, kwave_mat.FORMAT, scan.FORMAT, ipasc.FORMAT, dataset.FORMAT, result.FORMAT,
           unmix.FORMAT, plan.FORMAT, png.FORMAT, ome_tiff.FORMAT, ngff.FORMAT)
for _fmt in BUILTIN:
    register(_fmt)


def _discover() -> list[Format]:
    """Register the ``FORMAT`` of every other public module of this package (a format
    added as one file), in module-name order; returns them. A module without ``FORMAT``
    (``untrusted``: the hostile-file checks) is no format."""
    found = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        fmt = getattr(importlib.import_module(f"{__name__}.{info.name}"), "FORMAT", None)
        if isinstance(fmt, Format) and fmt.name not in FORMATS:
            found.append(register(fmt))
    return found


_discover()


def upload_formats() -> list[dict]:
    """The formats ``POST /api/datasets`` accepts, in order (``GET /api/datasets/formats``: the
    web page's and the HTTP client's choices).

    Returns
    -------
    list of dict
        ``{"name", "title", "wavelengths"}`` per format, ``wavelengths`` True where the format
        can hold several excitation wavelengths.
    """
    return [{"name": f.name, "title": f.title, "wavelengths": f.wavelengths}
            for f in FORMATS.values() if f.upload]
