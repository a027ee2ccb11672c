"""``linear``, ``nearest``, ``cubic``: FFT on the regular frequency grid + interpolation onto
the k-space image (k-Wave style; one algorithm, the interpolation its parameter; kernel:
:func:`service.recon.planar.reconstruct_grid`). For comparison with NER-NUFFT."""
from __future__ import annotations

from collections.abc import Callable
from functools import partial

from service.recon.methods import Method, planar_memory, register
from service.recon.methods.ner import run_grid
from service.recon.methods.options import DepthOptions, MethodOptions, PositivityOption, UpsampleOption

__all__ = ["Options", "KINDS", "METHODS"]


class Options(DepthOptions, PositivityOption, UpsampleOption, MethodOptions):
    """Options of the FFT + interpolation methods (no NUFFT tolerance)."""


#: name -> (title, source)
KINDS = {
    "linear": ("FFT + linear interpolation (k-Wave style)", "FFT on the regular frequency grid + linear interpolation"),
    "nearest": ("FFT + nearest-neighbour interpolation",
                "FFT on the regular frequency grid + nearest-neighbour interpolation"),
    "cubic": ("FFT + cubic (pchip) interpolation", "FFT on the regular frequency grid + pchip interpolation"),
}

_run: Callable = run_grid
METHODS = [register(Method(name, title, True, Options, partial(_run, name), source, planar_memory(name),
                           order=30 + k))
           for k, (name, (title, source)) in enumerate(KINDS.items())]
