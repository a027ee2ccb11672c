"""The reconstruction methods: one module per method, one registry.

Each module of this package (``ner``, ``nedner``, ``interp``, ``kwave``, ``tv``, and
whatever comes next) defines its typed options model (a :class:`~.options.MethodOptions`
with each option's type, range, unit and default), its ``run`` (calling the kernels of
:mod:`fpscan.service.recon`: ``planar``, ``kwave``, ``tv``) and its peak-memory model in a
:class:`Method` (``METHOD``). fpscan's own are registered in code when this package is imported;
another package's (a plugin: :mod:`fpscan.plugins`, docs/plugins.md) through an entry point of the
group ``fpscan.methods``, read on the registry's first lookup or listing
(``fpscan.service.plugins.PluginRegistry``). A new method is one new file (and, in a plugin, its
entry point): the dispatch (:func:`fpscan.service.pipeline.reconstruct`), the HTTP request (a union
keyed on ``method`` of each method's options model: ``fpscan.service.api.models.REQUEST_MODELS``),
``GET /api/reconstructions/methods`` (each option's JSON schema: the web page's fields), the
flags of ``fpscan recon`` / ``unmix``, the docs table (:func:`docs_table`) and what a
result's summary and a running job's progress line show of it (:attr:`Method.summary`,
:attr:`Method.stop_waits_for`) are generated from :data:`METHODS`.

The package is three modules: :mod:`.registry` (the :class:`Method` record, :data:`METHODS`,
:func:`register`, :func:`get`, :func:`default_for`), :mod:`.work` (the work and memory
estimators: :func:`planar_work`, :func:`peak_model`, ...) and :mod:`.render` (the options'
schemas and words: :func:`option_schemas`, :func:`docs_table`, ...); it re-exports their names.

``run(dataset, sound_speed, options, progress)``: ``dataset`` a
``fpscan.service.recon.dataset.GridDataset`` when the method ``needs_grid``, else a ``PointDataset``
(the pipeline converts); ``sound_speed`` in m/s (resolved: the request's, the dataset's or the
autofocus search's); ``options`` the method's validated options, an instance of its
``options_model`` (every field filled; ``dtype`` its name; ``None`` for "derived from the data",
e.g. ``n_z``); ``progress`` a
``fpscan.service.progress.Span``: ``progress(fraction, stage)`` or a kernel's ``progress(fraction)``
(stage "reconstructing"), fractions in [0, 1]. Returns a ``fpscan.service.recon.reconstruction.Reconstruction``.

Importing this package needs no numpy (the command line of a client-only install builds its
flags from it); the kernels load when a method runs.
"""
from __future__ import annotations

from fpscan.service.recon.methods.options import MethodOptions
from fpscan.service.recon.methods.registry import (
    INPUT_KINDS,
    METHODS,
    Method,
    default_for,
    describe_error,
    estimate_peak_memory,
    get,
    outcome,
    register,
)
from fpscan.service.recon.methods.render import (
    default_text,
    docs_table,
    option_fields,
    option_schemas,
    range_text,
)
from fpscan.service.recon.methods.work import (
    FLOAT64_WORK,
    PLANAR_WORK_RATE,
    peak_model,
    planar_work,
    transform_units,
)

__all__ = ["Method", "METHODS", "register", "get", "option_schemas", "option_fields", "docs_table",
           "peak_model", "estimate_peak_memory", "default_for", "INPUT_KINDS", "FLOAT64_WORK", "PLANAR_WORK_RATE",
           "transform_units", "planar_work", "MethodOptions", "default_text", "describe_error", "range_text",
           "outcome"]

def _register_builtins() -> None:
    """Fpscan's own methods, registered in code (the plugins' come from entry points, on the
    registry's first read: ``fpscan.service.plugins.PluginRegistry``)."""
    from fpscan.service.recon.methods import interp, kwave, nedner, ner, tv

    for method in (nedner.METHOD, ner.METHOD, *interp.METHODS, kwave.METHOD, tv.METHOD):
        register(method)


# last: a method module imports this package's names
_register_builtins()
METHODS.arm(Method, register)
