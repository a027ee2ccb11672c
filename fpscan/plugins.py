"""fpscan's plugin API: what another package builds on to add a reconstruction method or a
file format (docs/plugins.md; the gallery's "A delay-and-sum method as a plugin package").

Public and versioned (:data:`API_VERSION`): the names below keep their meaning within a major
version; a change that breaks a plugin raises the major version and the old names keep working,
with a ``DeprecationWarning``, for one release.

A method is a :class:`Method` (a keyword-only declaration) with

- its options: a subclass of :class:`MethodOptions` (every method's speed of sound
  ``sound_speed``, ``sound_speed_range``, ``force`` and ``dtype``) and of the mix-ins of the
  options it shares with fpscan's methods (:class:`NufftOptions`, :class:`UpsampleOption`,
  :class:`PositivityOption`, :class:`DepthOptions` (with :func:`depth_grid`, the grid its ``n_z`` and ``dz``
  mean), :class:`DeviceOption`), its own as typed
  pydantic fields with their range, unit (``json_schema_extra={"unit": ...}``) and default: the
  library, ``fpscan recon``'s flags, ``POST /api/reconstructions`` (its options model in the
  request's union) and the web page's fields are generated from them;
- its ``run(dataset, sound_speed, options, progress) -> Reconstruction``: ``dataset`` a
  :class:`GridDataset` when it ``needs_grid``, else a :class:`PointDataset` (the dispatch converts),
  ``sound_speed`` in m/s (resolved: the request's, the dataset's, or the autofocus search's),
  ``options`` an instance of its options model, validated once at the door, ``progress`` a
  :data:`Progress`: ``progress(fraction, stage)`` with fractions in [0, 1], where a cancel is heard;
- its memory and work models (``peak_memory``, ``work``: bytes and seconds on the reference 2
  cores), which the server's admission reads. A method that declares none is admitted by the
  conservative rules :func:`undeclared_peak` and :func:`undeclared_work` (32 float64 copies of the
  larger of its input and output; 50 ns per sensor and voxel), never by another method's figures.

A format is a :class:`Format` (``sniff``, ``load``, ``write``, ``export``).

fpscan's own methods and formats are registered in code; a package declares its own in the
entry-point groups ``fpscan.methods`` / ``fpscan.formats`` of its ``pyproject.toml``, which fpscan
reads on the first lookup or listing (:class:`fpscan.service.plugins.PluginRegistry`); or, in a
running process, :func:`register_method` / :func:`register_format`.

Examples
--------
A method that returns the A-lines' envelope as its "image" (a toy; the gallery builds a real one):

>>> import numpy as np
>>> from pydantic import Field
>>> import fpscan
>>> from fpscan.plugins import API_VERSION, Method, MethodOptions, Reconstruction, register_method
>>> API_VERSION
'1.1'
>>> class GainOptions(MethodOptions):
...     gain: float = Field(1.0, gt=0, le=100, description="a factor on the image", json_schema_extra={"unit": "1"})
>>> def run(ds, sound_speed, options, progress):
...     progress(0.5, "reconstructing")
...     z = np.arange(ds.data.shape[0]) * sound_speed * ds.dt
...     x = (np.arange(ds.data.shape[1]) - (ds.data.shape[1] - 1) / 2) * ds.dx
...     return Reconstruction(options.gain * np.abs(ds.data), z, x, None, {"gain": options.gain})
>>> toy = register_method(Method(name="toy-gain", title="a toy", needs_grid=True, options_model=GainOptions,
...                              run=run, order=1000))
>>> ds = fpscan.GridDataset(np.ones((8, 4)), dx=1e-4, dt=2e-8, sound_speed=1500.0)
>>> rec = fpscan.reconstruct(ds, "toy-gain", gain=3)
>>> float(rec.p0.max()), rec.params["method"], rec.params["gain"]
(3.0, 'toy-gain', 3.0)
>>> toy.memory(256, 64, 64) == fpscan.plugins.undeclared_peak(256, 64, 64)  # no model declared
True
>>> del fpscan.METHODS["toy-gain"]
"""
from __future__ import annotations

from fpscan.service.formats import Format, Source
from fpscan.service.formats import register as register_format
from fpscan.service.progress import Fraction, Progress, span
from fpscan.service.recon.checks import OptionError
from fpscan.service.recon.dataset import GridDataset, PointDataset
from fpscan.service.recon.depth import depth_grid
from fpscan.service.recon.methods import Method, MethodOptions, peak_model, planar_work
from fpscan.service.recon.methods import register as register_method
from fpscan.service.recon.methods.options import (
    DepthOptions,
    DeviceOption,
    Flag,
    NufftOptions,
    PositivityOption,
    UpsampleOption,
)
from fpscan.service.recon.methods.work import FLOAT64_WORK, undeclared_peak, undeclared_work
from fpscan.service.recon.reconstruction import Reconstruction

__all__ = [
    "API_VERSION", "Method", "MethodOptions", "NufftOptions", "UpsampleOption", "PositivityOption", "DepthOptions",
    "depth_grid", "DeviceOption", "Flag", "OptionError", "GridDataset", "PointDataset", "Reconstruction", "Progress", "Fraction",
    "span", "register_method", "peak_model", "planar_work", "undeclared_peak", "undeclared_work", "FLOAT64_WORK",
    "Format", "Source", "register_format",
]

#: the plugin API's version, ``"major.minor"``: a plugin written for major version 1 runs on any 1.x
API_VERSION = "1.1"
