"""tv end to end: `reconstruct_tv`, the model-based reconstruction, assembled from the package's parts.

`reconstruct_tv` checks the options (`fpscan.service.recon.tv.problem.check_options`), makes the
record at the band and on the grid the data can resolve (`fpscan.service.recon.tv.problem.working_record`,
`fpscan.service.recon.tv.grid`), then, on the device that runs it (`fpscan.service.recon.device.run`):
the warm start (`fpscan.service.recon.tv.problem.warm_start`), the model A and B = P Aᵀ
(`fpscan.service.recon.tv.problem.Model`), the step's ‖BA‖ and the noise image
(`fpscan.service.recon.tv.geometry`), λ and its continuation (`fpscan.service.recon.tv.lam`), the
solver (`fpscan.service.recon.tv.fista`) and the result's params (`fpscan.service.recon.tv.result`).
The problem and its source (Arridge et al., Phys. Med. Biol. 61 (2016) 8908): the package doc,
`fpscan.service.recon.tv`.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from fpscan.constants import C_DEFAULT
from fpscan.service.progress import Progress
from fpscan.service.recon import checks, limits
from fpscan.service.recon import device as devices
from fpscan.service.recon.reconstruction import Reconstruction
from fpscan.service.recon.tv.fista import MARGIN, debias_refit, run_fista
from fpscan.service.recon.tv.formulation import TvProblem, problem_of, set_up
from fpscan.service.recon.tv.lam import Continuation
from fpscan.service.recon.tv.problem import Record, check_options, start_image, working_record
from fpscan.service.recon.tv.progress import Reporter, final_stage
from fpscan.service.recon.tv.result import result_params

__all__ = ["DEFAULT_MAX_ITER", "DEFAULT_TOL", "DEFAULT_TIME_LIMIT", "reconstruct_tv", "tv_problem"]

#: default iteration limit of one model-based reconstruction (``fpscan.service.recon.limits``)
DEFAULT_MAX_ITER = limits.DEFAULT_MAX_ITER
#: the stopping rule: the image's relative change per iteration below this in each of the last 3
DEFAULT_TOL = limits.DEFAULT_TOL
#: default wall-time limit of one model-based reconstruction, s (``fpscan.service.recon.limits``; the
#: server's setting ``time_limit_s`` caps it there)
DEFAULT_TIME_LIMIT = limits.DEFAULT_TIME_LIMIT


def reconstruct_tv(
    data: np.ndarray,
    dt: float,
    c: float = C_DEFAULT,
    *,
    dx: float | None = None,
    positions: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    grid: np.ndarray | Sequence[npt.ArrayLike] | None = None,
    lam: float | None = None,
    positivity: bool = True,
    max_iter: int = DEFAULT_MAX_ITER,
    tol: float = DEFAULT_TOL,
    dtype: npt.DTypeLike = np.float64,
    eps: float = 1e-6,
    dz: float | None = None,
    n_z: int | None = None,
    t0: float = 0.0,
    periodic: bool = False,
    memory_limit: int | None = None,
    time_limit: float = DEFAULT_TIME_LIMIT,
    debias: bool = False,
    bandwidth: float | None = None,
    whole_record: bool = False,
    continuation: bool = True,
    progress: Progress | None = None,
    device: str = "auto",
    callback: Callable[[int, Any, float], None] | None = None,
) -> Reconstruction:
    """Model-based reconstruction: ½‖A p0 − g‖² + λ TV(p0), p0 ≥ 0 (package doc).

    Parameters
    ----------
    data : array_like
        Grid data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` (time first) with ``dx``, or A-lines
        ``(n_points, n_t)`` with ``positions``; Pa (or the instrument's unit).
    dt : float
        Sample interval, s.
    c : float, optional
        Sound speed, m/s (default ``fpscan.constants.C_DEFAULT``).
    dx : float, optional
        Lateral pitch in m (grid data; needed without ``positions``).
    positions : ndarray, optional
        Sensor positions ``(n_points, 1)`` x / ``(n_points, 2)`` (x, y) in m (A-lines).
    weights, grid : optional
        As `reconstruct_points` (weights ``(n_points,)``, default: clipped Voronoi areas,
        used by the NEDNER warm start only: the data term weighs every A-line equally; grid:
        default the positions' lattice; its x and y pitch must be equal).
    lam : float, optional
        TV weight λ (>= 0) in the data's unit; None (default): 0.6 × the image's noise
        level ‖P Aᵀ n̂‖_rms, raised where the warm start's discrepancy shows undersampling
        artefacts (package doc; `fpscan.service.recon.tv.lam`).
    positivity : bool, optional
        Constrain p0 >= 0 (default True).
    max_iter : int, optional
        Iterations at most (>= 1).
    tol : float, optional
        The stopping rule's threshold (>= 0; `fpscan.service.recon.tv.stopping`): stop when the image's relative
        change per iteration, ‖x_k − x_{k−1}‖ / ‖x_k‖, has been below ``tol`` in each of the
        last 3 iterations (0: run ``max_iter``).
    dtype : float32 or float64, optional
        Precision of the solver's vectors and of the output.
    eps : float, optional
        NUFFT tolerance.
    dz, n_z, t0 : optional
        Depth spacing (m), depth samples and time of sample 0 (s). With neither dz nor n_z
        given, `fpscan.service.recon.tv.grid.tv_grid`'s: dz = c / (2 f_c) at the operator's band f_c
        (the pitch, or a declared band; c dt at full band), down to the last echo's depth; a
        given one is kept and the other keeps its default (`fpscan.service.recon.depth`'s rule,
        every method's).
    periodic : bool, optional
        Model the grid as laterally periodic (no zero padding; `PlanarOperator`), as NER
        itself does: several times cheaper for large volumes, but sources near an edge wrap
        around to the far sensors.
    memory_limit : int, optional
        Bytes (default: available now).
    time_limit : float, optional
        Wall-time limit in s, in (0, 1 week] (default ``DEFAULT_TIME_LIMIT``, an hour): when
        it is reached the solver stops after the current iteration and says so in
        ``params`` (``converged`` false, ``stop_reason`` "time limit").
    debias : bool, optional
        After the solve, refit the amplitudes by least squares on tv's support
        (`fpscan.service.recon.tv.fista`: 10 more operator pairs). Default False.
    bandwidth : float, optional
        A sensor bandwidth the caller declares, Hz, in [1e3, 1e12]: the operator works at that
        band instead of the one the lateral pitch resolves (`fpscan.service.recon.tv.problem`).
    whole_record : bool, optional
        Keep the whole record and, without n_z, image its whole depth
        (`fpscan.service.recon.tv.problem`; `fpscan.service.recon.tv.grid.tv_grid`). Default False.
    continuation : bool, optional
        Start the TV weight at λ · D₀ and lower it to λ (`fpscan.service.recon.tv.lam`; default
        True); False steps at λ from the first iteration (the solver until 2026-11-26, kept
        for comparisons: the typed options of the API, CLI and web page keep the default).
    progress : callable, optional
        ``progress(fraction, stage)`` (the pipeline's contract), called
        with increasing fractions during the warm start (stage "warm start"), after each
        step of the norm estimate ("norm estimate") and every iteration ("iteration
        k/max_iter", "iteration k/max_iter (λ continuation k/K)" while λ still falls: an
        `fpscan.service.progress.IterationStage` with the rule's value, ``tol`` and the first
        iteration at which the rule can stop the run, K + 3), and again with the same fraction at most every 0.2 s inside long steps
        (the operator's checkpoints: `PlanarOperator` ``checkpoint``); it may raise to cancel
        (the pipeline's ``should_stop`` does), so a cancel acts within about a second even
        when one iteration takes minutes.
    device : {"auto", "cpu", "cuda"}, optional
        Where it runs (`fpscan.service.recon.device`; default ``"auto"``: the GPU where CuPy sees one,
        no other job holds it and the operator fits it). On the GPU the warm start, the operator
        pair, the preconditioner and the solver's steps all run there (`fpscan.service.recon.gpu`,
        `fpscan.service.recon.tv.kernels`); the operator needs the sensors on the image's lateral grid
        nodes (a scan plan's lattice).
    callback : callable, optional
        ``callback(k, x, J)`` after iteration k (1, 2, ...) of the solver: its iterate x
        ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` (Pa; the solver's array: NumPy, CuPy on a GPU; valid
        during the call only, copy it to keep it) and J(x) = ½‖A x − g‖² + λ TV(x) at λ (Pa²,
        exact: the solver computes A x anyway; `tv_problem`'s ``objective``). It may raise to
        stop the run (the exception propagates).

    Returns
    -------
    Reconstruction
        p0 ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` with ``z``, ``x``, ``y`` (m) on the warm
        start's grid; ``params`` add ``lam``, ``lam_auto``, ``lam_factor`` (λ over
        ``image_noise``; None for a given λ), ``lam_note`` (only when the automatic λ is 0:
        why — noiseless data), ``warm_discrepancy`` (D₀, `fpscan.service.recon.tv.lam`),
        ``lam_floored`` (the automatic λ is the reach floor's), ``lam_noise_level`` (the noise-level
        rule's λ before the floor), ``reach_unit`` (L max x₀, Pa), ``prox_reach`` (ρ = λ / (L max
        x₀), the proximal step's weight relative to the warm start's peak),
        ``noise_sigma`` (σ̂, Pa), ``image_noise``, ``noise_share``, ``lam_start_factor`` (the
        continuation's λ₀ / λ, 1 without one), ``continuation_iterations`` (iterations with λ_k >
        λ), ``stop_armed_at`` (the first iteration at which the stopping rule could stop the run:
        ``continuation_iterations`` + 3; None for ``tol`` 0), ``iterations``, ``residual``
        (‖A p0 − g‖ / ‖g‖), ``norm_A`` (‖P AᵀA‖, the step's L), ``converged`` (the stopping
        rule ``tol`` was met), ``stop_reason`` ("converged", "iterations": ``max_iter`` reached,
        "time limit"), ``iterate_change`` (the rule's last value), ``operator_pairs``,
        ``geometry_kept`` (‖BA‖ and the noise image were kept from a run on this geometry),
        ``exact_from`` (the first iteration of the solver's exact phase, whose fixed point is J's
        minimiser: `fpscan.service.recon.tv.fista`; None where the run ended in the preconditioned
        phase, as a run to the default ``tol`` does),
        ``solver``, ``debias``, ``time_limit``, ``solve_s``; and the grid: ``dt`` (the
        record's), ``record_n_t`` (the record's samples kept: after them the model predicts
        silence), ``extent_reason`` ("image", "record"), ``operator_dt``, ``operator_n_t``,
        ``band`` (Hz, None: Nyquist), ``band_reason`` ("lateral", "declared", "nyquist"),
        ``bandwidth`` (as declared); ``device`` (``"cpu"``/``"cuda"``), with ``device_name`` and
        ``device_fallback`` as `fpscan.service.recon.device.run` gives them.

    Raises
    ------
    ValueError
        Naming the problem: negative or non-finite λ, iterations < 1, NaN/inf data, grid
        data without ``dx``, weights of the wrong length, unequal x/y pitch, anything
        `reconstruct_grid` / `reconstruct_points` reject, estimated memory above the limit
        (an out-of-range option is a ``fpscan.service.recon.checks.OptionError``); ``device="cuda"``
        where the GPU cannot run it (`fpscan.service.recon.device.Unsuited`).
    fpscan.service.recon.device.GpuError
        The GPU failed during a ``device="cuda"`` run (``"auto"`` reruns on the CPU).

    References
    ----------
    .. [1] S. Arridge, P. Beard, M. Betcke, B. Cox, N. Huynh, F. Lucka, O. Ogunlade, E. Zhang,
       "Accelerated high-resolution photoacoustic tomography via compressed sensing", Phys.
       Med. Biol. 61 (2016) 8908.
    .. [2] A. Beck, M. Teboulle, "A fast iterative shrinkage-thresholding algorithm for linear
       inverse problems", SIAM J. Imaging Sci. 2 (2009) 183; "Fast gradient-based algorithms
       for constrained total variation image denoising and deblurring problems", IEEE Trans.
       Image Process. 18 (2009) 2419.
    .. [3] B. O'Donoghue, E. Candès, "Adaptive restart for accelerated gradient schemes",
       Found. Comput. Math. 15 (2015) 715.
    .. [4] D. L. Donoho, I. M. Johnstone, "Ideal spatial adaptation by wavelet shrinkage",
       Biometrika 81 (1994) 425 (the noise level of the automatic λ).

    Examples
    --------
    A 3 x 3 block (the exact forward model, `fpscan.physics.forward`) on a 16-sensor line:

    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon.tv import reconstruct_tv
    >>> p0 = np.zeros((12, 16))  # (n_z, n_x), pitch 0.1 mm
    >>> p0[5:8, 7:10] = 1.0
    >>> g = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=24, c=1500.0)  # (n_t, n_x)
    >>> r = reconstruct_tv(g, 1e-4 / 1500, 1500.0, dx=1e-4, n_z=12, max_iter=10)
    >>> r.p0.shape, r.p0.dtype, bool(r.p0.min() >= 0), r.params["iterations"], r.params["lam_auto"]
    ((12, 16), dtype('float64'), True, 10, True)
    >>> bool(np.corrcoef(r.p0.ravel(), p0.ravel())[0, 1] > 0.95)  # close to the true p0
    True
    >>> reconstruct_tv(g, 1e-4 / 1500, 1500.0)  # grid data without their pitch
    Traceback (most recent call last):
    ...
    ValueError: grid data need dx (or give positions for A-lines)
    >>> reconstruct_tv(g, 1e-4 / 1500, 1500.0, dx=1e-4, lam=-1)
    Traceback (most recent call last):
    ...
    fpscan.service.recon.checks.OptionError: lam (the TV weight λ) must be in [0, 1e+30], got -1
    """
    lam, max_iter, tol, time_limit = check_options(lam, max_iter, tol, time_limit)
    bandwidth = None if bandwidth is None else checks.check_bandwidth(bandwidth)
    rdtype = checks.check_dtype(dtype)
    started = time.monotonic()
    report = Reporter(progress)
    if positions is None and dx is None:
        raise ValueError("grid data need dx (or give positions for A-lines)")
    device = devices.check_device(device)
    # the record at the band and on the grid the data can resolve
    record = working_record(data, dt, c, dx, positions, grid, bandwidth=bandwidth, dz=dz, n_z=n_z, t0=t0,
                     whole_record=bool(whole_record))

    def solve(dev: str) -> Reconstruction:
        return _solve(record, dev, c=c, dx=dx, positions=positions, weights=weights, grid=grid, lam=lam,
                      positivity=positivity, max_iter=max_iter, tol=tol, rdtype=rdtype, eps=eps, t0=t0,
                      periodic=periodic, memory_limit=memory_limit, time_limit=time_limit, debias=debias,
                      bandwidth=bandwidth, whole_record=whole_record, continuation=continuation, dt=dt,
                      report=report, started=started, callback=callback)

    if device == "cpu":
        result = solve("cpu")
        result.params["device"] = "cpu"
        return result
    # the GPU's lock is held from the warm start to the last iteration (`fpscan.service.recon.device.run`)
    result, ran = devices.run(device, 0, lambda: solve("cuda"), lambda: solve("cpu"), poll=report.poll)
    result.params.update(ran)
    return result


def _solve(record: Record, dev: str, *, c: float, dx: float | None, positions: np.ndarray | None,
           weights: np.ndarray | None, grid: np.ndarray | Sequence[npt.ArrayLike] | None, lam: float | None,
           positivity: bool, max_iter: int, tol: float, rdtype: np.dtype, eps: float, t0: float, periodic: bool, memory_limit: int | None, time_limit: float,
           debias: bool, bandwidth: float | None, whole_record: bool, continuation: bool, dt: float,
           report: Reporter, started: float, callback: Callable[[int, Any, float], None] | None) -> Reconstruction:
    """`reconstruct_tv` on ``record`` from the warm start on, its operator pair on ``dev``
    (``"cpu"`` or ``"cuda"``; the warm start runs there too); the caller adds the device's facts
    to the params."""
    # the warm start, A and B = P Aᵀ, the step's ‖BA‖, the noise image and λ's rule: the problem
    # `tv_problem` gives a user (`fpscan.service.recon.tv.formulation`)
    parts = set_up(record, dev, report, c=c, dx=dx, positions=positions, weights=weights, grid=grid, dtype=rdtype,
                   eps=eps, t0=t0, positivity=positivity, periodic=periodic, memory_limit=memory_limit)
    warm, model, rule = parts.warm, parts.model, parts.rule
    geometry_kept = parts.geometry_kept
    L = MARGIN * parts.gain
    # λ: given, or the rule of the image's noise level and the warm start's discrepancy; continued from λ D₀
    schedule = Continuation(record.noise_norm) if continuation else None
    first = [model.xp.asarray(start_image(warm, rdtype, positivity))]  # handed over: run_fista reuses its memory
    axes, warm_params = (warm.z, warm.x, warm.y), warm.params
    del warm, parts  # its float64 image: the solver's x is a copy (float32) or that image itself
    solved = run_fista(model.forward, model.B, model.g_dev, first, rule if lam is None else lam, L, positivity,
                    max_iter, tol, started, time_limit, report, model.residual, poll=report.poll,
                    continuation=schedule, callback=callback, precondition=model.precondition)
    debiased = bool(debias and solved.stop_reason != "time limit" and bool((solved.x > 0).any()))
    if debiased:  # the amplitudes refit at λ = 0 on tv's support, from tv's image (handed over)
        box = [solved]
        del solved
        solved = debias_refit(model.forward, model.B, model.g_dev, box, started, time_limit, model.residual, report.poll)
    if model.xp is not np:  # a GPU run: the image and A x back here
        solved = solved._replace(x=model.xp.asnumpy(solved.x), Ax=model.xp.asnumpy(solved.Ax))
    params = result_params(warm_params, record, model, solved, rule, schedule,
                     dict(dt=dt, bandwidth=bandwidth, whole_record=whole_record, max_iter=max_iter, tol=tol,
                          dtype=rdtype, positivity=positivity, periodic=periodic, time_limit=time_limit),
                     lam_auto=lam is None, geometry_kept=geometry_kept, debiased=debiased, started=started)
    report(1.0, final_stage(solved.stop_reason, solved.iterations))
    return Reconstruction(solved.x.astype(rdtype, copy=False), *axes, params)


def tv_problem(
    data: np.ndarray,
    dt: float,
    c: float = C_DEFAULT,
    *,
    dx: float | None = None,
    positions: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    grid: np.ndarray | Sequence[npt.ArrayLike] | None = None,
    lam: float | None = None,
    positivity: bool = True,
    dtype: npt.DTypeLike = np.float64,
    eps: float = 1e-6,
    dz: float | None = None,
    n_z: int | None = None,
    t0: float = 0.0,
    periodic: bool = False,
    memory_limit: int | None = None,
    bandwidth: float | None = None,
    whole_record: bool = False,
) -> TvProblem:
    """The problem `reconstruct_tv` solves for these data, for any solver: the operator A (a
    ``pylops.LinearOperator``), the data g it fits, the warm start, the grid and λ
    (`fpscan.service.recon.tv.formulation.TvProblem`), made by `reconstruct_tv`'s own set-up
    (`fpscan.service.recon.tv.formulation.set_up`), on the CPU.

    p0 = argmin_{p >= 0} J(p) = ½ ‖A p − g‖² + λ TV(p) (Arridge et al., PMB 61 (2016) 8908): hand
    ``operator``, ``data``, ``gradient`` and ``lam`` to pylops' or pyproximal's solvers (e.g.
    ``pyproximal.optimization.primaldual.PrimalDual`` on ``pylops.VStack([operator, gradient])``),
    start them from ``warm_start``, and compare with tv by ``objective``.

    Parameters
    ----------
    data, dt, c, dx, positions, weights, grid, lam, positivity, dtype, eps, dz, n_z, t0, periodic, memory_limit, bandwidth, whole_record
        As `reconstruct_tv`'s (data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` with ``dx``, or A-lines
        ``(n_points, n_t)`` with ``positions``; s, m/s, m, Pa, Hz).

    Returns
    -------
    TvProblem
        ``operator``, ``data``, ``warm_start``, ``grid``, ``lam``, ``positivity``, the axes ``z``,
        ``x``, ``y`` (m), ``gradient``, ``preconditioner``, ``params``; ``objective(p)`` = J(p).
        Its cost: the warm start, 2.5 operator pairs for the step's norm and the noise image
        (none when this geometry's are kept) and one forward for the automatic λ.

    Raises
    ------
    ValueError
        As `reconstruct_tv` (bad options, data, grid; the memory above ``memory_limit``).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.forward import forward_grid
    >>> from fpscan.service.recon.tv.reconstruct import reconstruct_tv, tv_problem
    >>> p0 = np.zeros((12, 16)); p0[5:8, 7:10] = 1.0
    >>> g = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=24, c=1500.0)
    >>> pb = tv_problem(g, 1e-4 / 1500, 1500.0, dx=1e-4, n_z=12)
    >>> r = reconstruct_tv(g, 1e-4 / 1500, 1500.0, dx=1e-4, n_z=12, max_iter=10)
    >>> pb.lam == r.params["lam"], pb.warm_start.shape == r.p0.shape
    (True, True)
    >>> bool(pb.objective(r.p0) < pb.objective(pb.warm_start))  # tv lowers J
    True
    >>> tv_problem(g, 1e-4 / 1500, 1500.0)
    Traceback (most recent call last):
    ...
    ValueError: grid data need dx (or give positions for A-lines)
    """
    lam, _, _, _ = check_options(lam, 1, 0.0, DEFAULT_TIME_LIMIT)
    bandwidth = None if bandwidth is None else checks.check_bandwidth(bandwidth)
    rdtype = checks.check_dtype(dtype)
    if positions is None and dx is None:
        raise ValueError("grid data need dx (or give positions for A-lines)")
    record = working_record(data, dt, c, dx, positions, grid, bandwidth=bandwidth, dz=dz, n_z=n_z, t0=t0,
                            whole_record=bool(whole_record))
    parts = set_up(record, "cpu", Reporter(None), c=c, dx=dx, positions=positions, weights=weights, grid=grid,
                   dtype=rdtype, eps=eps, t0=t0, positivity=positivity, periodic=periodic, memory_limit=memory_limit)
    return problem_of(parts, record, lam, positivity)
