"""``tv``: model-based reconstruction, ½‖A p0 − g‖²_W + λ TV(p0) with p0 ≥ 0, solved by
NER-preconditioned FISTA on the exact planar model (kernel:
:func:`service.recon.tv.reconstruct_tv`; Arridge et al., PMB 61 (2016) 8908)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

from pydantic import BeforeValidator, Field

from service.recon.limits import (
    DEFAULT_MAX_ITER,
    DEFAULT_TIME_LIMIT,
    ITERATIONS_RANGE,
    LAM_RANGE,
    TIME_LIMIT_MAX,
)
from service.recon.methods import Method, planar_memory, register
from service.recon.methods.options import DepthOptions, Flag, MethodOptions, NufftOptions, kernel_rule

if TYPE_CHECKING:
    from service.progress import Progress
    from service.recon.dataset import PointDataset
    from service.recon.reconstruction import Reconstruction

__all__ = ["Options", "run", "METHOD"]

Lam = Annotated[Annotated[float, Field(ge=LAM_RANGE[0], le=LAM_RANGE[1])] | None,
                BeforeValidator(kernel_rule("check_lam"))]
Iterations = Annotated[Annotated[int, Field(ge=ITERATIONS_RANGE[0], le=ITERATIONS_RANGE[1])] | None,
                       BeforeValidator(kernel_rule("check_iterations"))]
TimeLimit = Annotated[Annotated[float, Field(gt=0, le=TIME_LIMIT_MAX)] | None,
                      BeforeValidator(kernel_rule("check_time_limit"))]


class Options(DepthOptions, MethodOptions, NufftOptions):
    """Options of ``tv`` (SI units; λ in the data's units)."""

    positivity: Flag("positivity") = Field(True, description="constrain p0 >= 0")  # type: ignore[valid-type]
    lam: Lam = Field(None, description="TV weight λ in the data's units",
                     json_schema_extra={"unit": "data units", "flag": "--lambda",
                                        "derived": "from the estimated noise level"})
    iterations: Iterations = Field(DEFAULT_MAX_ITER, description="maximum iterations of the solver",
                                   json_schema_extra={"unit": "1"})
    time_limit: TimeLimit = Field(DEFAULT_TIME_LIMIT, description="wall-time limit of the solver (the server's "
                                  "setting tv_time_limit_s caps it): when reached the result says converged false, "
                                  "stop reason 'time limit'", json_schema_extra={"unit": "s", "quantity": "time"})
    debias: Flag("debias") = Field(False, description="refit the amplitudes by least squares on the "  # type: ignore[valid-type]
                                   "support after the solve")


def run(ds: PointDataset, c: float, opts: dict, step: Progress) -> Reconstruction:
    """Model-based reconstruction of A-lines ``ds.alines`` ``(n, n_t)`` at ``ds.positions``
    (m), ``c`` in m/s; the progress stage names the iteration (``"iteration k/N"``).
    ValueError when there are no A-lines."""
    from service.recon import reconstruct_tv

    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    opts = dict(opts)
    iterations = opts.pop("iterations", None) or DEFAULT_MAX_ITER
    positivity = bool(opts.pop("positivity", True))
    return reconstruct_tv(ds.alines, ds.dt, c, positions=ds.positions, weights=ds.weights, grid=ds.grid,
                          t0=ds.t0, max_iter=iterations, positivity=positivity, progress=step, **opts)


METHOD = register(Method(
    "tv", "model-based: TV + positivity on the exact model (iterative; sparse, noisy scans)", False, Options, run,
    "½‖A p0 − g‖²_W + λ TV(p0), p0 ≥ 0, NER-preconditioned FISTA (Arridge et al., PMB 61 (2016) 8908)",
    planar_memory("tv"), order=50))
