"""``ner``: NER-NUFFT on a full regular grid (paper §3.1): a temporal NUFFT and a lateral
FFT (kernel: :func:`service.recon.planar.reconstruct_grid`)."""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from service.recon.methods import Method, planar_memory, register
from service.recon.methods.options import (
    DepthOptions,
    MethodOptions,
    NufftOptions,
    PositivityOption,
    UpsampleOption,
)

if TYPE_CHECKING:
    from service.recon.dataset import GridDataset
    from service.recon.reconstruction import Reconstruction

__all__ = ["Options", "run", "run_grid", "METHOD"]


class Options(DepthOptions, PositivityOption, UpsampleOption, MethodOptions, NufftOptions):
    """Options of ``ner`` (the fields of its mix-ins; SI units)."""


def run_grid(name: str, ds: GridDataset, c: float, opts: dict, step: Callable[[float], None]) -> Reconstruction:
    """``service.recon.planar.reconstruct_grid`` with ``method=name`` on grid data
    ``ds.data`` ``(n_t, n_y, n_x)`` or ``(n_t, n_x)``, ``c`` in m/s, the validated options."""
    from service.recon import reconstruct_grid

    dy = ds.dy if ds.data.ndim == 3 else None
    return reconstruct_grid(ds.data, ds.dx, ds.dt, c, method=name, dy=dy, t0=ds.t0, progress=step, **opts)


def run(ds: GridDataset, c: float, opts: dict, step: Callable[[float], None]) -> Reconstruction:
    """NER-NUFFT of grid data (:func:`run_grid`)."""
    return run_grid("ner", ds, c, opts, step)


METHOD = register(Method("ner", "NER-NUFFT (full regular grid)", True, Options, run,
                         "paper §3.1: temporal NUFFT, lateral FFT", planar_memory("ner"), order=20))
