"""File formats: one module per format, one registry.

Each module declares one :class:`Format` — its ``sniff`` (cheap detection from the file's
first bytes and, for HDF5, its root attributes and links), its ``load`` (and ``write``
where it has one), whether it is a reconstruction input and an upload choice — and this
package registers it. The registry serves format detection (:func:`detect`), loading by
name or from the content (:func:`load`), the lists of choices (:func:`names`: the
reconstruction's ``--format``, ``POST /api/datasets``'s ``format``, ``GET
/api/datasets/formats`` for the web page and the HTTP client) and the one place a file is
opened and checked (:func:`open_source`: opened once, the hostile-HDF5 checks of
``fpscan.service.formats.untrusted`` applied to every format).

==============  ==========  ==================================================  =====================
name            module      content                                             role
==============  ==========  ==================================================  =====================
``npy``         npy         NumPy array in k-Wave layout → GridDataset          input, upload
``fpscan``      scan        fpscan scan file → PointDataset                     input, upload
``dataset``     dataset     canonical dataset (``fpscan-dataset/1``)            input (server's own)
``result``      result      reconstruction result ``volume.h5`` → ResultVolume  output
``unmix``       unmix       unmixing result ``unmix.h5`` → dict                 output
``ipasc``       ipasc       IPASC HDF5 → PointDataset                           input, upload
``kwave-hdf5``  kwave_hdf5  HDF5 array in k-Wave layout → GridDataset           input, upload
``kwave-mat``   kwave_mat   k-Wave MAT-file (MAT v5, v7.3) → GridDataset         input, upload
``plan``        plan        plan JSON → plan dict                               refused as data
``png``         png         PNG picture → bytes                                 refused as data
``ome-tiff``    ome_tiff    p0 volume as OME-TIFF (from a result)               export
``ome-zarr``    ngff        p0 volume as OME-Zarr, NGFF 0.5 (from a result)     export (a folder)
``npz``         npz         p0 volume and axes as NumPy .npz (from a result)    export
``mat``         mat         p0 volume as MATLAB .mat, k-Wave layout (result)    export
==============  ==========  ==================================================  =====================

Exports: a format with ``export_from`` and ``export`` writes files of another (``result`` and
``fpscan`` export themselves, ``ipasc`` a scan file, ``ome-tiff`` / ``ome-zarr`` / ``npz`` / ``mat`` a result):
:func:`export_formats`, :func:`export_file` (the one dispatch of ``fpscan export``, ``GET
/api/jobs/{id}/export/{format}``, the HTTP client's ``export`` and the web page's downloads).

Adding a format: a module with ``sniff``, ``load`` (and ``write``; its load options as a
typed model of ``fpscan.service.formats.load_options``, ``Format.options``), or an ``export``, that
declares a ``FORMAT = Format(...)``, its line in this package's built-ins (``_register_builtins``;
another package's: an entry point of the group ``fpscan.formats``, read on the registry's first
lookup or listing, ``fpscan.service.plugins.PluginRegistry``: a plugin, :mod:`fpscan.plugins`) and
its test — nothing else: the CLI help, the API's choices, the web page and the HTTP client follow
from the registry (docs/plugins.md).
"""
from __future__ import annotations

from fpscan.service.formats.registry import (
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

__all__ = ["FORMATS", "HEAD_BYTES", "MAX_BYTES", "Format", "Source", "describe", "detect", "export_file",
           "export_formats", "load", "names", "open_source", "register", "sniff", "unregister", "upload_formats"]

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


def _register_builtins() -> None:
    """Fpscan's own formats, registered in code (the plugins' come from entry points, on the
    registry's first read: ``fpscan.service.plugins.PluginRegistry``)."""
    from fpscan.service.formats import (
        dataset,
        ipasc,
        kwave_hdf5,
        kwave_mat,
        mat,
        ngff,
        npy,
        npz,
        ome_tiff,
        plan,
        png,
        result,
        scan,
        unmix,
    )

    for module in (npy, kwave_hdf5, kwave_mat, scan, ipasc, dataset, result, unmix, plan, png, ome_tiff, ngff, npz,
                   mat):
        register(module.FORMAT)


# last: a format module imports this package's names
_register_builtins()
FORMATS.arm(Format, register)
