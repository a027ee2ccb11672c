"""``landweber``: projected Landweber iterations on the exact planar model, a toy iterative
method (issue 48.1: a method added as one file — options, run, memory model, warm-up,
admission class — reaches the library, the CLI, the HTTP API and the web page with no other
edit). x_{k+1} = P₊(x_k + τ Aᵀ(g − A x_k)), τ = 1.9 / ‖A‖² (‖A‖ by power iteration), on
``service.recon.operator.PlanarOperator`` (the operator tv solves on); it stops when the
image's relative change falls below ``tol`` (converged) or after ``iterations``.
Landweber, Amer. J. Math. 73 (1951) 615."""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from pydantic import Field

from service.recon.limits import DEFAULT_TOL
from service.recon.methods import Method, peak_model, register
from service.recon.methods.options import DepthOptions, Flag, MethodOptions, NufftOptions
from service.recon.methods.tv import Iterations, Tol

if TYPE_CHECKING:
    from service.progress import Progress
    from service.recon.dataset import PointDataset
    from service.recon.reconstruction import Reconstruction

__all__ = ["Options", "run", "warm_up", "METHOD"]


class Options(DepthOptions, MethodOptions, NufftOptions):
    """Options of ``landweber`` (SI units).

    Attributes
    ----------
    eps, dtype, n_z, dz
        As NEDNER's (the operator's NUFFT tolerance, precision, depth grid).
    positivity : bool
        Project onto p0 >= 0 after each step (default True).
    iterations : int
        Most iterations (default 50).
    tol : float
        Stop when ‖x_k − x_k−1‖ / ‖x_k‖ < tol (converged).

    Examples
    --------
    >>> from service.recon.methods.landweber import Options
    >>> Options(iterations=5).iterations, Options().positivity
    (5, True)
    """

    positivity: Flag("positivity") = Field(True, description="constrain p0 >= 0")  # type: ignore[valid-type]
    iterations: Iterations = Field(50, description="maximum iterations", json_schema_extra={"unit": "1"})
    tol: Tol = Field(DEFAULT_TOL, description="stop when the image's relative change per iteration is below tol",
                     json_schema_extra={"unit": "1"})


def run(ds: PointDataset, c: float, opts: dict, step: Progress) -> Reconstruction:
    """Projected Landweber iterations on A-lines ``ds.alines`` ``(n, n_t)`` at ``ds.positions``.

    Parameters
    ----------
    ds : PointDataset
        ``alines`` ``(n, n_t)`` at ``positions`` ``(n, 1)`` x / ``(n, 2)`` (x, y) in m on the
        lateral ``grid`` (its axes in m), ``dt`` and ``t0`` in s.
    c : float
        Speed of sound, m/s.
    opts : dict
        The validated options (every field of :class:`Options`; ``dtype`` a NumPy dtype).
    step : callable
        ``step(fraction, stage)``, called after each iteration (``"iteration k/N"``); it may
        raise to cancel.

    Returns
    -------
    Reconstruction
        p0 ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` on ``ds.grid``, z from 0 in steps of dz (m);
        ``params``: ``iterations``, ``converged``, ``stop_reason``, ``relative_change``.

    Raises
    ------
    ValueError
        No A-lines, or a grid the operator refuses.

    Examples
    --------
    >>> import numpy as np
    >>> from service.pipeline import reconstruct
    >>> from service.recon.dataset import GridDataset
    >>> data = np.zeros((48, 12), np.float32); data[20, 5:7] = 1.0
    >>> rec = reconstruct(GridDataset(data=data, dx=1e-4, dt=4e-8, c=1500.0), "landweber", iterations=3)
    >>> rec.p0.shape, rec.params["iterations"], rec.params["stop_reason"]
    ((48, 12), 3, 'iterations')
    """
    import numpy as np

    from service.recon.operator import PlanarOperator
    from service.recon.reconstruction import Reconstruction

    if ds.alines.shape[0] == 0:
        raise ValueError("the input has no A-lines to reconstruct")
    dtype = np.dtype(opts.get("dtype") or "float32")
    n_t = ds.alines.shape[1]
    dz = float(opts.get("dz") or c * ds.dt)
    n_z = int(opts.get("n_z") or n_t)
    axes = [np.asarray(g, dtype=float) for g in ds.grid]
    dx = float(axes[0][1] - axes[0][0]) if len(axes[0]) > 1 else c * ds.dt
    centre = np.array([a.mean() for a in axes])
    shape = (n_z, *(len(a) for a in reversed(axes)))  # (n_z, [n_y,] n_x)
    op = PlanarOperator(shape, dx, dz, ds.dt, n_t, c, positions=np.asarray(ds.positions) - centre, t0=ds.t0,
                        eps=float(opts.get("eps") or 1e-6), dtype=dtype)
    g = np.asarray(ds.alines, dtype=dtype)
    v = np.random.default_rng(0).standard_normal(shape).astype(dtype)
    for _ in range(8):  # power iteration for ‖A‖²
        v = op.adjoint(op.forward(v))
        norm = float(np.linalg.norm(v))
        v /= norm
    tau = 1.9 / norm
    x = np.zeros(shape, dtype)
    iterations, tol = int(opts["iterations"]), float(opts["tol"])
    stop, change, k = "iterations", float("inf"), 0
    for k in range(1, iterations + 1):
        new = x + tau * op.adjoint(g - op.forward(x))
        if opts.get("positivity", True):
            np.maximum(new, 0.0, out=new)
        change = float(np.linalg.norm(new - x) / max(float(np.linalg.norm(new)), 1e-30))
        x = new
        step(k / iterations, f"iteration {k}/{iterations}")
        if change < tol:
            stop = "converged"
            break
    z = np.arange(n_z) * dz
    params: dict[str, Any] = {"method": "landweber", "c": c, "iterations": k, "converged": stop == "converged", "stop_reason": stop,
                              "relative_change": change, "tau": tau}
    return Reconstruction(p0=x, z=z, x=axes[0], y=axes[1] if len(axes) > 1 else None,
                          params=params)


def warm_up(dtypes: Sequence[str]) -> None:
    """Nothing of its own: the operator's kernels are tv's (``Method.warm_up`` of ``tv``).

    Parameters
    ----------
    dtypes : sequence of str
        ``"float32"`` and/or ``"float64"`` (unused).

    Examples
    --------
    >>> from service.recon.methods.landweber import warm_up
    >>> warm_up(["float32"]) is None
    True
    """


METHOD = register(Method("landweber", "projected Landweber on the exact model (toy iterative method)", False,
                         Options, run, "Landweber, Amer. J. Math. 73 (1951) 615; the planar operator of tv",
                         peak_model("model_based_peak"), order=60, iterative=True, warm_up=warm_up,
                         kernel_modules=("service.recon.tv",), warm_in_background=True, memory_calibration=1.05,
                         holds_input=True))
