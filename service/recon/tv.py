"""Model-based reconstruction: total variation + positivity on the exact planar model.

Solves (DESIGN §3; Arridge, Beard, Betcke, Cox, Huynh, Lucka, Ogunlade, Zhang,
"Accelerated high-resolution photoacoustic tomography via compressed sensing",
Phys. Med. Biol. 61 (2016) 8908)::

    p0 = argmin_{p >= 0}  ½ ‖A p − g‖²_W + λ TV(p)

with A the exact planar forward model (`service.recon.operator.PlanarOperator`, free
space, sensors on the grid or at arbitrary positions), W the sensors' quadrature weights
normalised to mean 1 (W = I on a regular grid) and TV(p) = Σ_voxels |∇p|₂ the isotropic
total variation with forward differences in voxel units (so λ is in the units of p0,
Pa). Positivity is on by default (``positivity=False`` drops it).

Solver: the first-order primal-dual algorithm of Chambolle & Pock (2011) as implemented
by pyproximal (`pyproximal.optimization.cls_primaldual.PrimalDual`, stepped one
iteration at a time so that progress, cancellation and the stopping rule act between
iterations), on K = [A_w / L ; s ∇] with L ≈ ‖W^½ A‖ from a power iteration on A_wᴴA_w
(`_norm_estimate`: 10 steps from a seeded start vector, so one input gives one result;
×1.05 margin) and s = 1/(2√d) (‖∇‖ ≤ 2√d, d = image
dimensions), so ‖K‖² ≤ 2 and the steps τ = 0.99ρ/√2, σ = 0.99/(ρ√2) satisfy
τσ‖K‖² < 1 (ρ = 10 balances primal and dual progress; fastest on the tests' cases). The data
part is the proximal map of ½‖· − g_w/L‖², the TV part pyproximal's L21 norm with weight
λ/(L² s), the positivity pyproximal's Box. Warm start: the NER (grid) / NEDNER (points)
image. Stopping rule: relative change ‖p_k − p_{k−1}‖ / ‖p_k‖ below ``tol`` or
``max_iter`` iterations.

Automatic λ (``lam=None``, the default): λ = ‖W^½ A‖ σ̂, with σ̂ the noise standard
deviation estimated from the data by the median absolute deviation of the finest Haar
wavelet coefficients along time (Donoho & Johnstone 1994: σ̂ = median|g_{2n+1} − g_{2n}|
/ (√2 · 0.6745), robust to the sparse signal edges; `noise_sigma`). Rationale: with
AᵀWA ≈ ‖W^½A‖² I on what the sensors see, the problem is TV denoising of the
least-squares image, whose noise is σ̂/‖W^½A‖, with weight λ/‖W^½A‖²; a TV-denoising
weight equal to the image noise level is the classical choice, which gives the rule. It
is checked against a λ sweep on noisy 2-D and 3-D phantoms (tests). The λ used, σ̂ and
the final residual ‖A p0 − g‖_W (to compare with the noise level, the discrepancy
principle) are returned in ``params``.
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from driver.constants import C_DEFAULT
from service.recon import checks
from service.recon.reconstruction import Reconstruction

DEFAULT_MAX_ITER = 60
DEFAULT_TOL = 2e-3
#: default wall-time limit of one model-based reconstruction, s (the server's setting
#: ``tv_time_limit_s`` caps it there)
DEFAULT_TIME_LIMIT = 3600.0
_STEP_RATIO = 10.0  # τ/σ balance of the primal-dual steps (τσ fixed); fastest on the tests' cases


def noise_sigma(data: np.ndarray, time_axis: int) -> float:
    """Noise standard deviation of ``data`` (Pa), from the median absolute deviation of
    the finest Haar wavelet coefficients along ``time_axis`` (Donoho & Johnstone 1994):
    σ = median |g_{2n+1} − g_{2n}| / (√2 · 0.6745)."""
    g = np.moveaxis(np.asarray(data, dtype=np.float64), time_axis, -1)
    n = g.shape[-1] // 2 * 2
    if n < 2:
        return 0.0
    d = (g[..., 1:n:2] - g[..., 0:n:2]) / math.sqrt(2.0)
    return float(np.median(np.abs(d)) / 0.6745)


def _check_tv_options(lam, max_iter, tol, time_limit):
    """The model-based options by their rules (``service.recon.checks``: one owner each)."""
    lam = None if lam is None else checks.check_lam(lam)
    max_iter = checks.check_iterations(max_iter)
    tol = float(tol)
    if not np.isfinite(tol) or tol < 0:
        raise ValueError(f"tol must be a finite number >= 0, got {tol!r}")
    return lam, max_iter, tol, checks.check_time_limit(time_limit)


def reconstruct_tv(
    data: np.ndarray,
    dt: float,
    c: float = C_DEFAULT,
    *,
    dx: float | None = None,
    positions: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    grid=None,
    lam: float | None = None,
    positivity: bool = True,
    max_iter: int = DEFAULT_MAX_ITER,
    tol: float = DEFAULT_TOL,
    dtype=np.float64,
    eps: float = 1e-6,
    dz: float | None = None,
    n_z: int | None = None,
    t0: float = 0.0,
    periodic: bool = False,
    memory_limit: int | None = None,
    time_limit: float = DEFAULT_TIME_LIMIT,
    progress=None,
) -> Reconstruction:
    """Model-based reconstruction: ½‖A p0 − g‖²_W + λ TV(p0), p0 ≥ 0 (module doc).

    Parameters
    ----------
    data : grid data (n_t, n_x) / (n_t, n_y, n_x) (time first) with ``dx``, or A-lines
        (n_points, n_t) with ``positions`` (n_points, 1) x / (n_points, 2) (x, y) in m.
    dt : sample interval in s. c : sound speed in m/s.
    dx : lateral pitch in m (grid data). positions, weights, grid : as
        `reconstruct_points` (weights default: clipped Voronoi areas; grid: default the
        positions' lattice; its x and y pitch must be equal).
    lam : TV weight λ in Pa (>= 0); None (default): λ = ‖W^½A‖ σ̂ from the
        estimated noise level (module doc). positivity : constrain p0 >= 0 (default True).
    max_iter : iterations at most (>= 1). tol : stop when the relative change of p0 per
        iteration falls below it.
    dtype : float32 or float64 (solver vectors and output). eps : NUFFT tolerance.
    dz, n_z, t0 : as `reconstruct_grid`. periodic : model the grid as laterally periodic
        (no zero padding; `PlanarOperator`), as NER itself does: several times cheaper
        for large volumes, but sources near an edge wrap around to the far sensors.
    memory_limit : bytes (default: available now).
    time_limit : wall-time limit in s, in (0, 1 week] (default ``DEFAULT_TIME_LIMIT``, an
        hour): when it is reached the solver stops after the current iteration and says so
        in ``params`` (``converged`` false, ``stop_reason`` "time limit").
    progress : optional ``progress(fraction, stage)`` (the pipeline's contract), called
        with increasing fractions during the warm start (stage "warm start"), after each
        step of the norm estimate ("norm estimate") and every iteration ("iteration
        k/max_iter"); it may raise to cancel (the pipeline's ``should_stop`` does), so a
        cancel acts within one iteration.

    Returns
    -------
    `Reconstruction` (p0, z, x, y) on the warm start's grid; ``params`` add ``lam``, ``lam_auto``,
    ``noise_sigma``, ``iterations``, ``residual`` (‖A p0 − g‖_W / ‖g‖_W), ``norm_A``,
    ``converged`` (the stopping rule ``tol`` was met), ``stop_reason`` ("converged",
    "iterations": ``max_iter`` reached, "time limit"), ``time_limit``, ``solve_s``.

    Raises
    ------
    ValueError naming the problem: negative or non-finite λ, iterations < 1, NaN/inf data,
    weights of the wrong length, unequal x/y pitch, anything `reconstruct_grid` /
    `reconstruct_points` reject, estimated memory above the limit.
    """
    import pylops
    import pyproximal
    from pyproximal.optimization.cls_primaldual import PrimalDual

    from service.recon.operator import PlanarOperator
    from service.recon.planar import reconstruct_grid, reconstruct_points

    lam, max_iter, tol, time_limit = _check_tv_options(lam, max_iter, tol, time_limit)
    rdtype = checks.check_dtype(dtype)
    started = time.monotonic()
    report = _reporter(progress)
    common: dict[str, Any] = dict(dtype=np.float64, dz=dz, n_z=n_z, t0=t0, eps=eps, positivity=positivity,
                  memory_limit=memory_limit, progress=lambda f: report(0.05 * f, "warm start"))
    if positions is None:
        if dx is None:
            raise ValueError("grid data need dx (or give positions for A-lines)")
        warm = reconstruct_grid(data, dx, dt, c, **common)
        g = np.asarray(data, dtype=np.float64)
        pos, w = None, None
        dx = warm.params["dx"]
    else:
        warm = reconstruct_points(data, positions, dt, c, weights=weights, grid=grid, **common)
        g = np.asarray(data, dtype=np.float64)
        dx = warm.params["dx"]
        if warm.params.get("dy") is not None and not np.isclose(warm.params["dy"], dx, rtol=1e-9):
            raise ValueError(f"tv needs equal x and y pitch, got {dx} and {warm.params['dy']} m")
        pos = np.asarray(positions, dtype=np.float64).reshape(len(g), -1).copy()
        pos[:, 0] -= 0.5 * (warm.x[0] + warm.x[-1])
        if pos.shape[1] == 2 and warm.y is not None:  # 2-D lattice: y is set
            pos[:, 1] -= 0.5 * (warm.y[0] + warm.y[-1])
        if weights is None:
            from driver.physics.weights import voronoi_weights

            w = voronoi_weights(np.asarray(positions, dtype=np.float64).reshape(len(g), -1))
        else:
            w = np.asarray(weights, dtype=np.float64)
        if not np.all(w > 0):
            raise ValueError("weights must be > 0 for tv (a sensor of weight 0 carries no data)")
        w = w / w.mean()
    report(0.05, "warm start")
    dz_used, n_t = warm.params["dz"], g.shape[0] if pos is None else g.shape[1]
    shape = warm.p0.shape
    op = PlanarOperator(shape, dx, dz_used, dt, n_t, c, positions=pos, t0=t0, eps=eps, dtype=rdtype,
                         periodic=periodic)
    checks.check_memory(checks.tv_memory(shape, op.padded_shape, g.size, n_t, rdtype), memory_limit)
    sw = np.ones(op.oshape) if w is None else np.repeat(np.sqrt(w)[:, None], n_t, axis=1)
    Aw = pylops.Diagonal(sw.ravel().astype(rdtype), dtype=rdtype) @ op
    gw = (g * sw).ravel().astype(rdtype)
    x0 = np.ascontiguousarray(warm.p0, dtype=rdtype).ravel()

    L = 1.05 * _norm_estimate(Aw, x0.size, rdtype,
                              step=lambda k, n: report(0.05 + 0.05 * k / n, "norm estimate"))
    if not L > 0:
        raise ValueError("no sensor sees the image within the record (‖A‖ = 0): nothing to reconstruct")
    report(0.1, "norm estimate")
    d = len(shape)
    s = 1.0 / (2.0 * math.sqrt(d))
    grad = pylops.Gradient(shape, sampling=1.0, edge=False, kind="forward", dtype=rdtype)
    K = pylops.VStack([(1.0 / L) * Aw, s * grad])
    sigma = noise_sigma(g, 0 if pos is None else 1)
    auto = lam is None
    if auto:
        lam = L / 1.05 * sigma
    data_prox = pyproximal.L2(b=gw / L)
    if lam > 0:
        proxg = pyproximal.VStack([data_prox, pyproximal.L21(ndim=d, sigma=lam / (L * L * s))],
                                  nn=[gw.size, d * x0.size])
    else:  # plain (constrained) least squares: no TV block
        K, proxg = (1.0 / L) * Aw, data_prox
    proxf = pyproximal.Box(lower=0.0) if positivity else pyproximal.Box(lower=-np.inf, upper=np.inf)
    tau, mu = 0.99 / math.sqrt(2.0) * _STEP_RATIO, 0.99 / math.sqrt(2.0) / _STEP_RATIO
    solver = PrimalDual()
    x, xhat, y = solver.setup(proxf, proxg, K, x0, tau, mu, niter=None)
    it, stop_reason = 0, "iterations"
    for it in range(1, max_iter + 1):
        xold = x
        x, xhat, y = solver.step(x, xhat, y)
        change = float(np.linalg.norm(x - xold) / max(float(np.linalg.norm(x)), 1e-300))
        elapsed = time.monotonic() - started
        # the fraction: iterations done or time used, whichever is further (both increase)
        report(0.1 + 0.9 * min(1.0, max(it / max_iter, elapsed / time_limit)), f"iteration {it}/{max_iter}")
        if change < tol:
            stop_reason = "converged"
            break
        if elapsed >= time_limit and it < max_iter:
            stop_reason = "time limit"
            break
    p0 = x.reshape(shape).astype(rdtype, copy=False)
    res = Aw @ x - gw
    params = dict(warm.params)
    params.update(method="tv", warm_start=warm.params["method"], lam=float(lam), lam_auto=bool(auto),
                  noise_sigma=sigma, iterations=it, max_iter=max_iter, tol=tol, dtype=rdtype.name,
                  residual=float(np.linalg.norm(res) / max(float(np.linalg.norm(gw)), 1e-300)), norm_A=L / 1.05,
                  positivity=bool(positivity), weights_mean_one=w is not None, periodic=bool(periodic),
                  solver="pyproximal PrimalDual", converged=stop_reason == "converged", stop_reason=stop_reason,
                  time_limit=time_limit, solve_s=time.monotonic() - started)
    report(1.0, f"done after {it} iterations" + (" (time limit reached)" if stop_reason == "time limit" else ""))
    return Reconstruction(p0, warm.z, warm.x, warm.y, params)


def _norm_estimate(op, n: int, dtype, steps: int = 10, step=None) -> float:
    """‖op‖ (largest singular value) by ``steps`` power iterations on opᴴop from a
    seeded random start vector, so that one input always gives one result (pylops'
    ``power_iteration`` draws its start from NumPy's global random state, which made
    repeated reconstructions differ in the last digits). Slightly below the true norm
    (the caller adds a margin). ``step(k, steps)`` (optional) is called after step k."""
    v = np.random.default_rng(0).standard_normal(n).astype(dtype)
    v /= np.linalg.norm(v)
    eig = 0.0
    for k in range(steps):
        w = op.H @ (op @ v)
        eig = float(np.linalg.norm(w))
        if eig == 0.0:
            return 0.0
        v = (w / eig).astype(dtype, copy=False)
        if step is not None:
            step(k + 1, steps)
    return math.sqrt(eig)


def _reporter(progress):
    last = [0.0]

    def report(f: float, stage: str) -> None:
        if progress is not None and f > last[0]:
            last[0] = f
            progress(f, stage)

    return report
