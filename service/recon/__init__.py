"""Planar photoacoustic reconstruction: pure functions on numpy arrays, no I/O.

- `reconstruct_grid`: data on a regular sensor line/plane -> p0 (NER-NUFFT by default;
  FFT + linear/nearest/cubic interpolation for comparison).
- `reconstruct_points`: A-lines at arbitrary sensor positions -> p0 (NEDNER-NUFFT).
- `kspace_line_recon`, `kspace_plane_recon`: drop-in equivalents of k-Wave's
  kspaceLineRecon / kspacePlaneRecon.
- `forward_grid`, `forward_points`: the exact planar forward model (from
  `fpscan.physics`, the physics module the simulator shares).
- `PlanarOperator`: the forward model and its true adjoint as a pylops LinearOperator.
- `reconstruct_tv`: model-based reconstruction (TV + positivity, NER-preconditioned FISTA).
- `voronoi_weights`: default area weights for non-equispaced sensors (from
  `fpscan.physics.weights`, which owns them).
- `estimate_peak_memory`: bytes a reconstruction needs at its peak (admission control).

Importing the package imports nothing heavy: every name is imported on first use
(PEP 562; `Reconstruction` and `estimate_peak_memory` with numpy, and
`fpscan.service.recon.methods`, the method registry, loads without numpy), so scipy.fft, numba and
finufft load with the grid/points reconstruction, scipy.interpolate with the k-Wave
``*cubic`` mode, pylops/pyproximal (which take longer to import than everything else together)
with the model-based part, the plans package with `voronoi_weights`. A process that
only checks a request (`estimate_peak_memory`) or holds a `Reconstruction` never pays
for them.

numba compiles the kernels on their first call and caches them (``cache=True``) in
``__pycache__`` beside their modules, or under ``NUMBA_CACHE_DIR`` where that is set;
where the package directory is not writable numba falls back to a user cache directory
of its own. Any first call fills the cache, ``fpscan warmup`` (`fpscan.service.recon.warmup`) for
every kernel and precision at once, so the first reconstruction in a fresh interpreter
loads compiled code.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["Reconstruction", "GRID_METHODS", "reconstruct_grid", "reconstruct_points", "kspace_line_recon",
           "kspace_plane_recon", "forward_grid", "forward_points", "voronoi_weights",
           "estimate_peak_memory", "PlanarOperator", "reconstruct_tv"]

_LAZY = {"Reconstruction": "fpscan.service.recon.reconstruction", "estimate_peak_memory": "fpscan.service.recon.methods",
         "GRID_METHODS": "fpscan.service.recon.planar", "reconstruct_grid": "fpscan.service.recon.planar",
         "reconstruct_points": "fpscan.service.recon.planar", "PlanarOperator": "fpscan.service.recon.operator",
         "reconstruct_tv": "fpscan.service.recon.tv",
         "voronoi_weights": "fpscan.physics.weights", "kspace_line_recon": "fpscan.service.recon.kwave",
         "kspace_plane_recon": "fpscan.service.recon.kwave", "forward_grid": "fpscan.physics.forward",
         "forward_points": "fpscan.physics.forward"}

if TYPE_CHECKING:
    from fpscan.physics.forward import forward_grid, forward_points
    from fpscan.physics.weights import voronoi_weights
    from fpscan.service.recon.kwave import kspace_line_recon, kspace_plane_recon
    from fpscan.service.recon.methods import estimate_peak_memory
    from fpscan.service.recon.operator import PlanarOperator
    from fpscan.service.recon.planar import GRID_METHODS, reconstruct_grid, reconstruct_points
    from fpscan.service.recon.reconstruction import Reconstruction
    from fpscan.service.recon.tv import reconstruct_tv


def __getattr__(name: str) -> Any:
    """The reconstruction (scipy.fft, numba, finufft), `PlanarOperator`, `reconstruct_tv`
    (they load pylops), `voronoi_weights` (the plans package), the k-Wave modes
    (their ``*cubic`` mode: scipy.interpolate) and the forward model on first use."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'fpscan.service.recon' has no attribute {name!r}")
