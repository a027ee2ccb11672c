"""``nedner``: NEDNER-NUFFT for any sensor mask (paper §3.2): a temporal NUFFT and a type-1
NUFFT over the sensor positions (kernel: :func:`service.recon.planar.reconstruct_points`)."""
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
    from service.recon.dataset import PointDataset
    from service.recon.reconstruction import Reconstruction

__all__ = ["Options", "run", "METHOD"]


class Options(DepthOptions, PositivityOption, UpsampleOption, MethodOptions, NufftOptions):
    """Options of ``nedner`` (the fields of its mix-ins; SI units)."""


def run(ds: PointDataset, c: float, opts: dict, step: Callable[[float], None]) -> Reconstruction:
    """NEDNER-NUFFT of A-lines ``ds.alines`` ``(n, n_t)`` at ``ds.positions`` ``(n, 2)`` (m),
    ``c`` in m/s; ValueError when there are no A-lines."""
    from service.recon import reconstruct_points

    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    # NEDNER = NUFFT in time (the "ner" temporal step) + type-1 NUFFT over the positions
    return reconstruct_points(ds.alines, ds.positions, ds.dt, c, weights=ds.weights, grid=ds.grid,
                              method="ner", t0=ds.t0, progress=step, **opts)


METHOD = register(Method("nedner", "NEDNER-NUFFT (any sensor mask)", False, Options, run,
                         "paper §3.2: temporal NUFFT + type-1 NUFFT over the sensor positions",
                         planar_memory("nedner"), order=10))
