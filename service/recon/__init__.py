"""Planar photoacoustic reconstruction: pure functions on numpy arrays, no I/O.

- `reconstruct_grid`: data on a regular sensor line/plane -> p0 (NER-NUFFT by default;
  FFT + linear/nearest/cubic interpolation for comparison).
- `reconstruct_points`: A-lines at arbitrary sensor positions -> p0 (NEDNER-NUFFT).
- `kspace_line_recon`, `kspace_plane_recon`: drop-in equivalents of k-Wave's
  kspaceLineRecon / kspacePlaneRecon.
- `forward_grid`, `forward_points`: the exact planar forward model (from
  `driver.physics`, the physics module the simulator shares).
- `voronoi_weights`: default area weights for non-equispaced sensors.
- `estimate_peak_memory`: bytes a reconstruction needs at its peak (admission control).

The names are imported on first use, so that `service.recon.weights` (used by
`service.plans`) does not pull in numba and finufft.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "Image": "service.recon.image",
    "METHODS": "service.recon.planar",
    "reconstruct_grid": "service.recon.planar",
    "reconstruct_points": "service.recon.planar",
    "kspace_line_recon": "service.recon.kwave",
    "kspace_plane_recon": "service.recon.kwave",
    "forward_grid": "driver.physics.forward",
    "forward_points": "driver.physics.forward",
    "voronoi_weights": "service.recon.weights",
    "estimate_peak_memory": "service.recon.checks",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'service.recon' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(list(globals()) + __all__)
