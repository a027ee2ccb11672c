"""Model-based reconstruction: total variation + positivity on the exact planar model.

Solves (DESIGN §3; Arridge, Beard, Betcke, Cox, Huynh, Lucka, Ogunlade, Zhang,
"Accelerated high-resolution photoacoustic tomography via compressed sensing",
Phys. Med. Biol. 61 (2016) 8908)::

    p0 = argmin_{p >= 0}  J(p) = ½ ‖A p − g‖² + λ TV(p)

with A the exact planar forward model (`service.recon.operator.PlanarOperator`, free
space, sensors on the grid or at arbitrary positions), every A-line weighted equally (each
carries white noise of the same σ, so this is the maximum-likelihood data term; the
sensors' quadrature weights belong to NEDNER, the warm start, and also made the solver
slower: on the 3 % equi-steradian test mask 0.70 CC after 25 iterations against 0.88) and
TV(p) = Σ_voxels |∇p|₂ the isotropic
total variation with forward differences in voxel units (J in Pa², so λ is in Pa). Positivity is on by default (``positivity=False`` drops it).

Solver (issue 19): accelerated proximal gradient (FISTA, Beck & Teboulle 2009) preconditioned
by NER. NER is the adjoint with its k-space weight k_z / |k| (`service.recon.planar`: F =
const · (k_z/ω) E against the adjoint's E): for a full planar aperture AᵀA has the symbol
|k| / k_z, so P = k_z / |k| (`_ner_weight`, on the orthonormal DCT-II of the image
zero-padded to fast lengths, symmetric and positive definite) inverts it. Each iteration takes one forward A and one adjoint Aᵀ
(one operator pair) and steps along P Aᵀ (A y − g) (one adjoint of the residual: no
separate Aᵀg) with step 1 / L, L ≈ ‖P AᵀA‖ from two seeded power iterations (about 0.7 of
‖P AᵀA‖ on the test cases: fewer steps, or one from the noise image P Aᵀ n̂, land lower,
0.55-0.6, and the late-detected instability costs quality), raised (×1.1) whenever the
gain of P AᵀA along the last move of the iterates exceeds it (free: those products are
computed anyway). The proximal map of λ TV + positivity is gradient projection on the dual
(Chambolle 2005; Beck & Teboulle 2009's GP), warm-started from the previous iteration's dual
(no operator). Beck & Teboulle's fast variant (FGP) needs the dual's extrapolation, d images
more, for the same results here: on the twelve cases of tests/recon/test_recon_tv_solver.py
(blobs and vessels, 2-D and 3-D, 20, 30 and 40 dB) the same CC to 0.001 and the same
iterations to one, with 5 warm-started inner steps either way. Momentum: a constant
β = `_MOMENTUM` = 0.94 (y_{k+1} = x_{k+1} + β (x_{k+1} − x_k)), set to 0 for one step (a
restart) when J rises or the momentum points uphill (O'Donoghue & Candès 2015). A constant
β is Nesterov's scheme for a strongly convex objective, β = (1 − √q) / (1 + √q) with q the
inverse condition number (Nesterov, "Introductory Lectures on Convex Optimization", 2004,
§2.2.1): 0.94 is q ≈ 1e-3, and with the restarts it stands in for the unknown q, as in
the greedy FISTA of Liang, Luo & Schönlieb (arXiv:1811.01430, β = 1 with restarts).
Measured on the cases of tests/recon/test_recon_tv_solver.py at 30 dB (iterations and
operator pairs to the stopping rule, CC with the true p0), against Beck & Teboulle's
sequence β_k = (t_k − 1) / t_{k+1}: 2-D balls 21 / 24 pairs, 0.989 (24 / 27, 0.988),
2-D vessels 19 / 22, 0.986 (21 / 24, 0.985), 3-D balls 26 / 29, 0.984 (30 / 33, 0.977),
3-D vessels 20 / 23, 0.958 (24 / 27, 0.948); on the 3-D cases the CC is also higher after
any fixed count of 15 to 60 iterations. β = 1 (3-D balls: 27 pairs) ends on the 3-D
vessels at an image that loses its thinnest branch's contrast (below half the true one) and
whose automatic λ is no longer within 0.01 CC of the sweep's best; β = 0.9 loses CC on the
2-D balls. At λ = 0 without positivity the fixed point is the least-squares solution; with λ > 0 it is the fixed point of the P-preconditioned
proximal step (the minimiser of J exactly when the step's metric is Euclidean; P makes
it the NER-weighted one — a preconditioned, not a different, data term). pyproximal's
``ProximalGradient`` is not used because it evaluates the objective with extra operator
applications every step; here J(x) = ½‖Ax − g‖² + λ TV(x) is exact and free, A x being
computed anyway. Warm start: the NER (grid) / NEDNER (points) image in the working dtype,
clipped to >= 0.

Grid (issues 47 and 59; `service.recon.tv_grid`): the operator works at the band the lateral
pitch resolves, c / (2 pitch) (or a sensor bandwidth the caller declares, ``bandwidth``), not at
the record's own sampling: the data are low-passed and resampled exactly to the fewest samples
whose band reaches it (`driver.physics.resample`), the operator is band-limited there in
k-space (`PlanarOperator` ``band``), and the default depth grid is isotropic (dz = the pitch)
down to the depth of the record's last echo above the noise. The record is kept until the
farthest sensor hears the image's last row (3-D; a line keeps its whole record): after that the
model predicts silence, so the cut drops only noise and shortens the operator's record and
lateral padding. A given dz or n_z is kept, the other then c dt or n_t as before;
``whole_record`` keeps the whole record and images its whole depth. The band no longer comes
from the data: read per A-line, it fell far below what the coherent image uses on sparse noisy
scans (k-Wave's vessel tree at 4 % of the points, 20 dB below the peak: 0.79 MHz and CC 0.36,
against 0.96 now; docs/results.md, "tv's quality gate"). ``params`` record ``record_n_t``,
``extent_reason``, ``whole_record``, ``operator_dt``, ``operator_n_t``, ``band`` (Hz or None) and
``band_reason``; the noise image and the residuals are those of the kept, resampled data, and σ̂
that of the record as sampled, scaled to the resampled rate (white noise resampled from K to M
samples keeps √((M − 1) / (K − 1)) of its σ; the Haar estimate on the resampled record itself, whose
signal is no longer smooth at its sample scale, read 7-48 % high on k-Wave's data).

Stopping rule (``tol``, default `DEFAULT_TOL` = 5e-3; ``max_iter`` default
`DEFAULT_MAX_ITER` = 100): the image's relative change per iteration, ‖x_k − x_{k−1}‖ /
‖x_k‖ (free: summed with the momentum's test, `_moves`), below ``tol`` in each of the last
`_WINDOW` = 3 iterations ("converged"); else ``max_iter`` iterations ("iterations") or the
time limit ("time limit"). ``params`` say which, with the rule's last value
(``iterate_change``) and the operator pairs used (``operator_pairs``: (forward + adjoint
applications) / 2, everything included: the power iterations, the noise image of the
automatic λ, A of the warm start — 3 pairs before the first iteration —, every iteration and
``debias``). The step's ‖BA‖ estimate and the noise image's RMS depend on the geometry alone
(operator, P, seeded starts): they are kept for the last few geometries (`_GEOMETRY`), so a
repeated scan plan spends half a pair before its first iteration and gets the image a fresh
process computes (``params["geometry_kept"]``). Until 2026-11-24 the rule was on the objective (its mean decrease over the
last 3 iterations below 1e-3 of its decrease since the warm start). It stopped after 17-29
iterations while the image was still changing: on 3 % equi-steradian masks in 3-D the CC
with the true p0 rose by another 0.02-0.10 on the way to the minimiser (0.872 → 0.939 on the
vessel tree at 30 dB), because J is flat along the directions the sparse data leave to TV.
On 30 cases (docs/results.md, "When tv has converged") the rule on the image stops within
0.007 CC of the CC after 100 iterations, after 29-65 iterations (48 on average). It stops
farther from the minimiser as the case grows: at the paper's size (226² lattice, 776 samples kept,
1653 points) after 60 iterations with CC 0.964 against 0.991 after 300 at the same λ (tol 2e-3:
230 iterations, 0.991; docs/performance.md, "2026-11-26, morning"; with the continuation below,
66 iterations and 0.980). A second part on the path of
the run's second half (its changes summed below 40 tol) was measured and not built: it needs a
new automatic λ that no rule of s and D₀ found serves both sparse vessel trees and the paper's
balls, and at the paper's full size it too stopped short (docs/performance.md, "2026-11-26, later").

Continuation (``continuation=True``, the default; ``params`` ``lam_start_factor`` and
``continuation_iterations``): iteration k takes its proximal step with λ_k = λ · max(1, D₀ ·
0.9^(k−1)) (`_Continuation`, `_CONTINUATION_RATE`), from λ D₀ down to λ, and the restart test
compares J at λ_k; the stopping rule's window holds iterations at λ itself only. D₀ =
‖A x₀ − g‖ / (σ̂ √N) is the warm start's discrepancy (the automatic λ's, computed for a given λ
too; at least 1, and capped so that λ is reached within half of ``max_iter``). What sets the
numbers: the warm start's residual is D₀ noise norms, so its undersampling artefacts stand
about D₀ times above the noise that λ is scaled to; the directions the data leave to TV move
by about λ_k / L a step (docs/performance.md, "why tv's iterations resist"), so a weight of
that order clears them D₀ times faster, while the directions the data see, which converge
fast, restore what the strong weight flattened as λ_k falls. λ_k falls by 0.9 an iteration
(halves every 6.6 iterations, within the momentum's memory 1 / (1 − β) ≈ 17): 0.85 was also
measured, and start factors of 4-64 times λ, on the test cases and the paper's scan at half
size. Measured (docs/performance.md, "2026-11-26, evening"; iterations and CC with the true p0
at the stopping rule, without → with): 3-D balls at 3.3 % of a 40 × 40 lattice 66 → 58,
0.983 → 0.987; 3-D vessels there 72 → 66, 0.946 → 0.948; the 10 % masks 46-50 → 41-45, CC
within 0.001; the 2-D lines −0.002 to +0.003 (28-40 → 29-39 iterations); the paper's scan
(`benchmarks/bench_tv_paper.py`) 60 → 66 iterations, 0.964 → 0.980, at half its size 79 → 71,
0.975 → 0.983.

Memory: the TV part works in place (`_tv_prox`'s compiled sweeps step the dual in place;
`_tv_norm` needs no work array), the dual waits between iterations in half the working
precision's bytes (int16 fixed point for float32, `_store_dual`), the gradient step is made
in y's place, the preconditioner P is computed voxel by voxel where it is applied (no image
of its own), and two vectors wait as 16-bit fixed point with their quantum max|·| / 32767:
the last preconditioned gradient, which only the next gain test reads (`_store_gradient`;
the test subtracts what the rounding can add, so it stays a lower bound of ‖BA‖), and the
last move b = x − x_prev, from which y = x + β b was made (`_store_move`): x is not kept
beside y but read back as y − β q round(b / q), exactly, so only y, the extrapolation
point, carries the rounding (at most β q / 2 a voxel, vanishing with the moves; on the
test cases the same iterations, L and CC to 5 digits). While the operator works the solver
then holds 1 image, the dual's d/2 and two halves (`_fista`;
`service.recon.memory.tv_memory`); the operator's image and data k-space share one array
(`service.recon.operator.PlanarOperator`). At the paper's size the peak is 7.6 images (8.3
before the two fixed-point vectors), inside the proximal map (its dual at full precision
beside the stored one) and the operator alike; of those, about 0.4 is the C heap's pool of
the operator's chunk arrays, which glibc keeps after they are freed (its ``malloc_trim``
after each application gave 7.2, and cost 5 % of a pair: not done).

Automatic λ (``lam=None``, the default): λ = 0.6 s · max(1, (D₀ / 9.5)^0.25). s = ‖P Aᵀ n̂‖_rms is
the image's noise level: the RMS over the image of the preconditioned adjoint of one seeded
white-noise realisation n̂ of the estimated noise level σ̂ (one extra adjoint; σ̂ from the
median absolute deviation of the finest Haar wavelet coefficients along time, Donoho &
Johnstone 1994: σ̂ = median|g_{2n+1} − g_{2n}| / (√2 · 0.6745), robust to the sparse signal
edges; `noise_sigma`). Rationale: with P AᵀA ≈ c I, the problem is TV denoising of the
least-squares image (noise ‖P Aᵀ n‖ / c) with weight λ / c; a denoising weight of the order
of the image's noise level is the classical choice and c cancels. On a sparse mask the
image's error is mostly undersampling artefacts, not noise: D₀ = ‖A x₀ − g‖ / (σ̂ √N), the
warm start's discrepancy in units of the noise's norm (free: the solver's first forward),
measures them — about 2-10 where the warm start fits the data to a few noise norms, 17-51 on
3 % equi-steradian masks — and raises λ mildly there. The scale 0.6, the knee 9.5 and the
power 0.25 are calibrated at the stopping rule's default, on 30 cases: 3-D balls and vessel
trees on equi-steradian masks of 3-10 % of a 40 × 40 lattice at two lateral pitches and
2-D lines of 24 sensors, 20-40 dB (docs/results.md, "When tv has converged"), where λ lands
within 0.007 CC of the best of a ×1/8 … ×8 sweep (within 0.008 on 20 cases the fit never
saw). (The rule before, s · max(1, (D₀ / 9.5)^0.75), was calibrated on images the
objective's rule had stopped early; on converged images it was too strong for vessels, by
up to 0.06 CC.) ``params`` return λ, s
(``image_noise``), D₀ (``warm_discrepancy``), the factor (``lam_factor``), σ̂ and the
data's noise share (``noise_share`` = σ̂ √N / ‖g‖, to compare with ``residual`` = ‖A p0 −
g‖ / ‖g‖: the discrepancy principle).

Debiasing (``debias=True``): TV shrinks amplitudes; afterwards `_DEBIAS_ITER` iterations of
the same solver at λ = 0 on tv's support (voxels above `_SUPPORT_FRACTION` of the maximum;
zero elsewhere, positivity kept) refit the amplitudes by least squares.
"""
from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import numba
import numpy as np
import numpy.typing as npt
import scipy.fft

from driver.constants import C_DEFAULT
from driver.physics.fast_lengths import fast_real_shape
from driver.physics.resample import resample
from service.progress import IterationStage, Progress, span
from service.recon import checks, memory
from service.recon import limits as _limits
from service.recon.reconstruction import Reconstruction
from service.recon.tv_grid import TvGrid, noise_sigma, tv_grid

if TYPE_CHECKING:
    from service.recon.operator import PlanarOperator

__all__ = ["DEFAULT_MAX_ITER", "DEFAULT_TOL", "DEFAULT_TIME_LIMIT", "TvGrid", "noise_sigma", "reconstruct_tv", "tv_grid"]

DEFAULT_MAX_ITER = _limits.DEFAULT_MAX_ITER
#: the stopping rule: the image's relative change per iteration below this in each of the last 3
DEFAULT_TOL = _limits.DEFAULT_TOL
_POWER_STEPS = 2  # power iterations for the first step 1 / ‖BA‖ (the solver raises L where it sees more)
_MARGIN = 1.1  # step 1 / (_MARGIN ‖BA‖)
#: the automatic λ = image noise level × _LAM_SCALE × max(1, (D₀ / _LAM_KNEE) ** _LAM_POWER),
#: D₀ the warm start's discrepancy over the noise's norm (module doc; calibrated on
#: docs/results.md's sweep at the stopping rule's default)
_LAM_SCALE = 0.6
_LAM_KNEE = 9.5
_LAM_POWER = 0.25
_MOMENTUM = 0.94  # the momentum β between restarts (constant: module doc)
_WINDOW = 3  # the stopping rule's window of iterations
_CONTINUATION_RATE = 0.9  # λ_k / λ_{k−1} while λ continues down to λ (module doc, "Continuation")
#: inner (dual, no operator) iterations of the TV + positivity proximal map, warm-started from
#: the last call's dual. 3, 5, 10 and 20 gave the same result on the vessels experiment (48 x
#: 96², 981 sensors: CC 0.9838-0.9839, 21 iterations, converged); at 256 x 128² (533-sensor
#: equi-steradian mask, float32) 5 and 10 gave the same 20 iterations and images 0.18 % apart
#: (3: 0.5 %), and 5 passes every λ sweep and convergence test; 5 instead of 10 made that run
#: 17 % faster (21.8 s against 26.3 s) (all with FGP, before gradient projection replaced it)
_PROX_ITER = 5
_DEBIAS_ITER = 10  # iterations of the least-squares refit on the support (debias)
_SUPPORT_FRACTION = 0.05  # the support for debias: p0 above this share of its maximum
_POLL_S = 0.2  # a cancel is polled at least this often (s) inside long steps
#: default wall-time limit of one model-based reconstruction, s (``service.recon.limits``; the
#: server's setting ``time_limit_s`` caps it there)
DEFAULT_TIME_LIMIT = _limits.DEFAULT_TIME_LIMIT


def _check_tv_options(lam: float | None, max_iter: int, tol: float,
                      time_limit: float) -> tuple[float | None, int, float, float]:
    """The model-based options by their rules (``service.recon.checks``: one owner each)."""
    lam = None if lam is None else checks.check_lam(lam)
    max_iter = checks.check_iterations(max_iter)
    tol = checks.check_tol(tol)
    return lam, max_iter, tol, checks.check_time_limit(time_limit)


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
) -> Reconstruction:
    """Model-based reconstruction: ½‖A p0 − g‖² + λ TV(p0), p0 ≥ 0 (module doc).

    Parameters
    ----------
    data : array_like
        Grid data ``(n_t, n_x)`` / ``(n_t, n_y, n_x)`` (time first) with ``dx``, or A-lines
        ``(n_points, n_t)`` with ``positions``; Pa (or the instrument's unit).
    dt : float
        Sample interval, s.
    c : float, optional
        Sound speed, m/s (default ``driver.constants.C_DEFAULT``).
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
        artefacts (module doc).
    positivity : bool, optional
        Constrain p0 >= 0 (default True).
    max_iter : int, optional
        Iterations at most (>= 1).
    tol : float, optional
        The stopping rule's threshold (>= 0; module doc): stop when the image's relative
        change per iteration, ‖x_k − x_{k−1}‖ / ‖x_k‖, has been below ``tol`` in each of the
        last 3 iterations (0: run ``max_iter``).
    dtype : float32 or float64, optional
        Precision of the solver's vectors and of the output.
    eps : float, optional
        NUFFT tolerance.
    dz, n_z, t0 : optional
        Depth spacing (m), depth samples and time of sample 0 (s). With neither dz nor n_z
        given, `service.recon.tv_grid.tv_grid`'s: dz = c / (2 f_c) at the operator's band f_c
        (the pitch, or a declared band; c dt at full band), down to the last echo's depth; a
        given one is kept and the other follows the record's own rule (c dt, n_t).
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
        After the solve, refit the amplitudes by least squares on tv's support (module doc;
        `_DEBIAS_ITER` more operator pairs). Default False.
    bandwidth : float, optional
        A sensor bandwidth the caller declares, Hz, in [1e3, 1e12]: the operator works at that
        band instead of the one the lateral pitch resolves (module doc, "Grid").
    whole_record : bool, optional
        Keep the whole record and, with neither dz nor n_z given, image its whole depth
        (module doc, "Grid"; `service.recon.tv_grid.tv_grid`). Default False.
    continuation : bool, optional
        Start the TV weight at λ · D₀ and lower it to λ (module doc, "Continuation"; default
        True); False steps at λ from the first iteration (the solver until 2026-11-26, kept
        for comparisons: the typed options of the API, CLI and web page keep the default).
    progress : callable, optional
        ``progress(fraction, stage)`` (the pipeline's contract), called
        with increasing fractions during the warm start (stage "warm start"), after each
        step of the norm estimate ("norm estimate") and every iteration ("iteration
        k/max_iter"), and again with the same fraction at most every 0.2 s inside long steps
        (the operator's checkpoints: `PlanarOperator` ``checkpoint``); it may raise to cancel
        (the pipeline's ``should_stop`` does), so a cancel acts within about a second even
        when one iteration takes minutes.

    Returns
    -------
    Reconstruction
        p0 ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` with ``z``, ``x``, ``y`` (m) on the warm
        start's grid; ``params`` add ``lam``, ``lam_auto``, ``lam_factor`` (λ over
        ``image_noise``; None for a given λ), ``lam_note`` (only when the automatic λ is 0:
        why — noiseless data), ``warm_discrepancy`` (D₀, module doc),
        ``noise_sigma`` (σ̂, Pa), ``image_noise``, ``noise_share``, ``lam_start_factor`` (the
        continuation's λ₀ / λ, 1 without one), ``continuation_iterations`` (iterations with λ_k >
        λ), ``iterations``, ``residual``
        (‖A p0 − g‖ / ‖g‖), ``norm_A`` (‖P AᵀA‖, the step's L), ``converged`` (the stopping
        rule ``tol`` was met), ``stop_reason`` ("converged", "iterations": ``max_iter`` reached,
        "time limit"), ``iterate_change`` (the rule's last value), ``operator_pairs``,
        ``geometry_kept`` (‖BA‖ and the noise image were kept from a run on this geometry),
        ``solver``, ``debias``, ``time_limit``, ``solve_s``; and the grid: ``dt`` (the
        record's), ``record_n_t`` (the record's samples kept: after them the model predicts
        silence), ``extent_reason`` ("image", "record"), ``operator_dt``, ``operator_n_t``,
        ``band`` (Hz, None: Nyquist), ``band_reason`` ("lateral", "declared", "nyquist"),
        ``bandwidth`` (as declared).

    Raises
    ------
    ValueError
        Naming the problem: negative or non-finite λ, iterations < 1, NaN/inf data, grid
        data without ``dx``, weights of the wrong length, unequal x/y pitch, anything
        `reconstruct_grid` / `reconstruct_points` reject, estimated memory above the limit
        (an out-of-range option is a ``service.recon.checks.OptionError``).

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
    A 3 x 3 block (the exact forward model, `driver.physics.forward`) on a 16-sensor line:

    >>> import numpy as np
    >>> from driver.physics.forward import forward_grid
    >>> from service.recon.tv import reconstruct_tv
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
    service.recon.checks.OptionError: lam (the TV weight λ) must be in [0, 1e+30], got -1
    """
    from service.recon.operator import PlanarOperator
    from service.recon.planar import reconstruct_grid, reconstruct_points

    lam, max_iter, tol, time_limit = _check_tv_options(lam, max_iter, tol, time_limit)
    bandwidth = None if bandwidth is None else checks.check_bandwidth(bandwidth)
    rdtype = checks.check_dtype(dtype)
    started = time.monotonic()
    report = _reporter(progress)
    if positions is None and dx is None:
        raise ValueError("grid data need dx (or give positions for A-lines)")
    # the grid the data can resolve (`service.recon.tv_grid`): the operator's samples and band,
    # the image's depth grid; the data low-passed and resampled to those samples
    time_axis = 0 if positions is None else 1
    g = np.asarray(checks.finite_array("data" if positions is None else "alines", data, (2, 3)), dtype=np.float64)
    if g.shape[time_axis] < 2:
        raise ValueError(f"data need at least 2 time samples, got shape {g.shape}")
    pitch, reach = _lateral_extent(g, dx, positions, grid)
    # σ̂ of the record as sampled (Haar differences need a signal smooth at the sample scale, which the record
    # resampled to its band is not: there they read 7-48 % high on k-Wave's data); resampling white noise of σ
    # from K to M samples leaves σ √((M − 1) / (K − 1)) per sample (the DCT-I terms kept)
    record_sigma = noise_sigma(g, time_axis)
    g, chosen = _working_record(g, dt, c, time_axis, sigma=record_sigma, bandwidth=bandwidth, dz=dz, n_z=n_z, t0=t0,
                                whole_record=bool(whole_record), pitch=pitch, reach=reach)
    dt_op = chosen.dt
    common: dict[str, Any] = dict(dtype=rdtype, dz=chosen.dz, n_z=chosen.n_z, t0=t0, eps=eps, positivity=positivity,
                  memory_limit=memory_limit, progress=span(report, 0.0, 0.05, "warm start"))
    if positions is None:
        assert dx is not None  # checked above
        warm = reconstruct_grid(g, dx, dt_op, c, **common)
        pos = None
        dx = warm.params["dx"]
    else:
        warm = reconstruct_points(g, positions, dt_op, c, weights=weights, grid=grid, **common)
        dx = warm.params["dx"]
        if warm.params.get("dy") is not None and not np.isclose(warm.params["dy"], dx, rtol=1e-9):
            raise ValueError(f"tv needs equal x and y pitch, got {dx} and {warm.params['dy']} m")
        pos = np.asarray(positions, dtype=np.float64).reshape(len(g), -1).copy()
        pos[:, 0] -= 0.5 * (warm.x[0] + warm.x[-1])
        if pos.shape[1] == 2 and warm.y is not None:  # 2-D lattice: y is set
            pos[:, 1] -= 0.5 * (warm.y[0] + warm.y[-1])
    report(0.05, "warm start")
    dz_used, n_t = warm.params["dz"], g.shape[time_axis]
    shape = warm.p0.shape
    op = PlanarOperator(shape, dx, dz_used, dt_op, n_t, c, positions=pos, t0=t0, eps=eps, dtype=rdtype,
                         periodic=periodic, checkpoint=report.poll, band=chosen.band)
    kept_columns = None if chosen.band is None else memory.band_columns(op.padded_shape, dx, c, chosen.band)
    checks.check_memory(memory.tv_memory(shape, op.padded_shape, g.size, n_t, rdtype, kept_columns=kept_columns),
                        memory_limit)
    # B = P Aᵀ: the exact adjoint, NER's k-space weight P = k_z / |k| (symmetric, positive definite)
    P = _ner_weight(shape, dx, dz_used)

    applied = [0, 0]  # forward, adjoint applications: params' operator_pairs is their mean

    def B(r: np.ndarray) -> np.ndarray:
        applied[1] += 1
        return _apply_weight(P, op.rmatvec(r.astype(rdtype, copy=False).ravel()).reshape(shape))

    def forward(v: np.ndarray) -> np.ndarray:
        applied[0] += 1
        return op.matvec(v.ravel()).reshape(g.shape)

    gw_norm = float(np.linalg.norm(g))
    sigma = record_sigma * math.sqrt((chosen.n_t - 1) / (chosen.record_n_t - 1))  # at the operator's rate
    noise_share = sigma * math.sqrt(g.size) / max(gw_norm, 1e-300)
    report(0.06, "norm estimate")  # the operator's set-up and the first adjoint: no longer the warm start

    # step: 1 / L with L ≈ ‖BA‖ (power iteration from a seeded white image) and a margin; and
    # the noise image B n̂ of one seeded white-noise record n̂ of unit σ, whose RMS times σ̂ is
    # the image's noise level (the automatic λ). Both depend on the geometry alone (the
    # operator, P and the seeds), so they are kept per geometry (`_GEOMETRY`): the same scan
    # plan again costs no pairs for them, and gets the same numbers a fresh process computes
    key = _geometry_key(op, shape, dx, dz_used, pos, rdtype, g.shape)
    kept = _GEOMETRY.get(key)
    geometry_kept = kept is not None
    norm = span(report, 0.05, 0.1, "norm estimate")
    if kept is None:
        start = np.random.default_rng(0).standard_normal(shape).astype(rdtype)
        gain = _gain_estimate(lambda v: B(forward(v)), start, _POWER_STEPS, step=lambda k, n: norm(k / n))
        del start
        noise_image = B(np.random.default_rng(0).standard_normal(g.shape)).ravel()
        noise_rms = math.sqrt(float(np.einsum("i,i->", noise_image, noise_image, dtype=np.float64))
                              / noise_image.size)  # accumulated in float64
        del noise_image
        kept = (gain, noise_rms)
        _GEOMETRY.put(key, kept)
    gain, noise_rms = kept
    L = _MARGIN * gain
    if not L > 0:
        raise ValueError("no sensor sees the image within the record (‖A‖ = 0): nothing to reconstruct")
    report(0.1, "norm estimate")
    image_noise = sigma * noise_rms
    auto = lam is None
    rule = _DiscrepancyRule(image_noise, sigma * math.sqrt(g.size))
    x = np.ascontiguousarray(warm.p0, dtype=rdtype)
    if positivity:
        np.maximum(x, 0, out=x)
    z_axis, x_axis, y_axis, warm_params = warm.z, warm.x, warm.y, warm.params
    del warm  # its float64 image: the solver's x is a copy (float32) or that image itself
    def residual(Ax: np.ndarray) -> float:
        return float(np.linalg.norm(Ax - g))

    first = [x]  # handed over: _fista reuses its memory, and this frame keeps no reference
    del x
    schedule = _Continuation(sigma * math.sqrt(g.size)) if continuation else None
    x, it, stop_reason, change, Ax, L, lam = _fista(forward, B, g, first, rule if lam is None else lam, L,
                                                    positivity, max_iter, tol, started, time_limit, report,
                                                    residual, poll=report.poll, continuation=schedule)
    debiased = False
    if debias and stop_reason != "time limit" and np.any(x > 0):
        support = x > _SUPPORT_FRACTION * float(np.max(x))
        first = [x]
        del x
        x, _, _, _, Ax, L, _ = _fista(forward, B, g, first, 0.0, L, True, _DEBIAS_ITER, 0.0, started,
                                      time_limit, None, residual, support=support, poll=report.poll)
        debiased = True
    p0 = x.astype(rdtype, copy=False)
    res = Ax - g
    params = dict(warm_params)
    params.update(dt=dt, operator_dt=dt_op, operator_n_t=n_t, band=chosen.band, band_reason=chosen.reason,
                  bandwidth=bandwidth, record_n_t=chosen.record_n_t, extent_reason=chosen.extent_reason,
                  whole_record=bool(whole_record))
    params.update(method="tv", warm_start=warm_params["method"], lam=float(lam), lam_auto=bool(auto),
                  lam_factor=rule.factor if auto else None, warm_discrepancy=rule.warm_discrepancy,
                  lam_start_factor=schedule.start_factor if schedule else 1.0,
                  continuation_iterations=schedule.iterations if schedule else 0,
                  noise_sigma=sigma, image_noise=image_noise, noise_share=noise_share, iterations=it,
                  max_iter=max_iter, tol=tol, dtype=rdtype.name,
                  residual=float(np.linalg.norm(res) / max(gw_norm, 1e-300)),
                  norm_A=L / _MARGIN, positivity=bool(positivity), weights_mean_one=False, data_weights="equal",
                  periodic=bool(periodic), solver="FISTA preconditioned by " + ("NER" if pos is None else "NEDNER"),
                  iterate_change=change if math.isfinite(change) else None,
                  operator_pairs=0.5 * (applied[0] + applied[1]), geometry_kept=geometry_kept, debias=debiased,
                  converged=stop_reason == "converged", stop_reason=stop_reason,
                  time_limit=time_limit, solve_s=time.monotonic() - started)
    if auto and lam == 0:  # said, not silent: on noiseless data the automatic λ has nothing to scale
        params["lam_note"] = ("the data show no noise (σ̂ = 0: the finest wavelet coefficients along time vanish), "
                              "so the automatic λ is 0, a least-squares fit" + (" with positivity" if positivity else "")
                              + "; set λ (--lambda; lam over HTTP) for a TV weight")
    report(1.0, ("converged" if stop_reason == "converged" else "stopped") + f" after {it} iterations"
           + {"time limit": " (time limit)", "iterations": " (iteration limit)"}.get(stop_reason, ""))
    return Reconstruction(p0, z_axis, x_axis, y_axis, params)


def _lateral_extent(g: np.ndarray, dx: float | None, positions: np.ndarray | None,
                    grid: np.ndarray | Sequence[npt.ArrayLike] | None) -> tuple[float | None, float | None]:
    """(pitch, reach) of tv's image for `service.recon.tv_grid.tv_grid`: its lateral pitch (m;
    None where the warm start will refuse the positions or grid) and the largest lateral distance
    between a sensor and a corner of its lateral extent (m; None in 2-D: a 2-D wave does not end
    when its front has passed, its tail ∝ 1/t² lasts to the record's end, so a line keeps its
    whole record; in 3-D, Huygens' principle: silence after the last front). Grid data ``(n_t, n_x)`` /
    ``(n_t, n_y, n_x)`` with ``dx``; A-lines with ``positions`` on ``grid`` (default: the
    positions' lattice, as `service.recon.planar.reconstruct_points` makes it)."""
    from service.recon.planar import _check_grid, _default_grid  # the warm start's own lattice and grid rules

    if positions is None:
        if dx is None or not (math.isfinite(dx) and dx > 0):
            return None, None
        sides = [(n - 1) * dx for n in g.shape[1:]]
        return float(dx), (math.hypot(*sides) if len(sides) == 2 else None)
    try:
        pos = np.asarray(positions, dtype=np.float64).reshape(len(g), -1)
        if grid is None:
            axes, pitch = _default_grid(pos)
        else:
            axes = _check_grid(grid, pos.shape[1])
            pitch = float(axes[0][1] - axes[0][0])
    except (ValueError, IndexError, TypeError):  # the warm start refuses them, naming the problem
        return None, None
    if not (math.isfinite(pitch) and pitch > 0):
        return None, None
    if pos.shape[1] == 1:  # a line: 2-D waves ring on (a tail ∝ 1/t² after the last front), keep it all
        return pitch, None
    far = np.zeros(len(pos))
    for a, ax in enumerate(axes):  # per axis, the farther of the extent's two ends
        far += np.maximum(np.abs(pos[:, a] - float(ax.min())), np.abs(pos[:, a] - float(ax.max()))) ** 2
    return pitch, float(np.sqrt(far.max())) if len(far) else None


def _working_record(g: np.ndarray, dt: float, c: float, time_axis: int, **grid: Any) -> tuple[np.ndarray, TvGrid]:
    """The record tv works on and its grid (`service.recon.tv_grid.tv_grid` with ``grid``'s
    keywords): ``g`` cut where the model of the image predicts silence (unless ``whole_record``)
    and resampled to the band, time along ``time_axis``."""
    chosen = tv_grid(g.shape[time_axis], dt, c, data=g, time_axis=time_axis, **grid)
    if chosen.cut:  # after it the model of the image predicts silence at every sensor (module doc)
        g = np.ascontiguousarray(g[: chosen.record_n_t] if time_axis == 0 else g[:, : chosen.record_n_t])
    if chosen.resampled:
        g = resample(g, chosen.n_t, axis=time_axis)
    return g, chosen


class _NerWeight(NamedTuple):
    """NER's k-space weight P = k_z / |k| (`_ner_weight`), kept as its axes, not as an image:
    ``kz`` ``(N_z,)`` and ``lat2`` = |k_lat|² ``(N_y, N_x)`` (2-D: ``(1, N_x)``), rad/m and
    rad²/m², float64; ``shape`` the padded grid ``(N_z, N_x)`` / ``(N_z, N_y, N_x)``."""

    kz: np.ndarray
    lat2: np.ndarray
    shape: tuple[int, ...]


def _ner_weight(shape: Sequence[int], dx: float, dz: float) -> _NerWeight:
    """NER's k-space weight k_z / |k| on the orthonormal DCT-II grid of the image zero-padded
    to fast lengths (`driver.physics.fast_lengths.fast_real_shape`: on axes of 226 = 2·113 the
    DCT-II and its inverse took 2.08 s at 1024 × 226², against 0.57 s at 1024 × 240², float32;
    mirror boundaries at the padded grid's ends; k_i = π j / (N_i d_i), depth shifted by
    half a bin so that the weight is > 0 everywhere), in (0, 1]: the inverse of AᵀA's symbol
    |k| / k_z for a full planar aperture.

    Parameters
    ----------
    shape : tuple of int
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``.
    dx, dz : float
        Lateral and depth spacing, m.

    Returns
    -------
    _NerWeight
        The weight's axes on the padded grid ``fast_real_shape(shape)`` (same axis order):
        P is computed voxel by voxel where it is applied (`_apply_weight`), so that it costs
        no image of memory. `_apply_weight` applies it as x -> crop(DCTᵀ P DCT pad(x)), a
        symmetric positive definite map of the image (the zero padding is an isometry and
        its adjoint the crop); on a grid that is already fast it is the image's own DCT-II."""
    grid = fast_real_shape(tuple(int(n) for n in shape))
    ks = [np.pi * np.arange(n) / (n * d) for n, d in zip(grid, (dz,) + (dx,) * (len(grid) - 1))]
    kz = ks[0] + np.pi / (2 * grid[0] * dz)  # half a depth bin: k_z > 0, so P is positive definite
    lat2 = sum(k * k for k in np.meshgrid(*ks[1:], indexing="ij", sparse=True))  # |k_lat|², grid[1:]
    lat2 = np.ascontiguousarray(np.broadcast_to(lat2, grid[1:]), dtype=np.float64).reshape(-1, grid[-1])
    return _NerWeight(kz, lat2, grid)


@numba.njit(parallel=True, cache=True, fastmath=True)
def _weight_kernel(c: np.ndarray, kz: np.ndarray, lat2: np.ndarray) -> None:
    """c[i, j, l] *= kz[i] / sqrt(kz[i]² + lat2[j, l]) in place (c: DCT coefficients, 3-D)."""
    for i in numba.prange(c.shape[0]):
        k = kz[i]
        k2 = k * k
        for j in range(c.shape[1]):
            row = c[i, j]
            lat = lat2[j]
            for m in range(c.shape[2]):
                row[m] *= k / math.sqrt(k2 + lat[m])


def _apply_weight(P: _NerWeight, x: np.ndarray) -> np.ndarray:
    """P x: the multiplier ``P`` (`_ner_weight`, on the padded grid ``P.shape``) on the
    orthonormal DCT-II of ``x`` zero-padded to that grid (all axes), cropped back; ``x`` is
    overwritten and returned, in its dtype (the transform runs in place when no axis is
    padded)."""
    pad = [(0, N - n) for N, n in zip(P.shape, x.shape)]
    padded = any(after for _, after in pad)
    c = scipy.fft.dctn(np.pad(x, pad) if padded else x, type=2, norm="ortho", workers=-1, overwrite_x=True)
    c = np.ascontiguousarray(c)  # (the kernel writes through a 3-D view of it)
    _weight_kernel(c.reshape(P.shape[0], P.lat2.shape[0], P.shape[-1]), P.kz, P.lat2)
    c = scipy.fft.idctn(c, type=2, norm="ortho", workers=-1, overwrite_x=True)
    if not padded:
        return c
    x[...] = c[tuple(slice(0, n) for n in x.shape)]
    return x


def _gain_estimate(apply: Callable[[np.ndarray], np.ndarray], start: np.ndarray, steps: int,
                   step: Callable[[int, int], None] | None = None) -> float:
    """Largest gain ‖BA v‖ / ‖v‖ of ``apply`` (= B A, B the NER/NEDNER of a residual) by
    ``steps`` power iterations from ``start`` (an image; not modified)."""
    v = start / np.linalg.norm(start)
    gain = 0.0
    for k in range(steps):
        u = np.asarray(apply(v), dtype=v.dtype).reshape(v.shape)
        gain = float(np.linalg.norm(u))
        if gain == 0.0:
            return 0.0
        v = np.divide(u, gain, out=u)
        if step is not None:
            step(k + 1, steps)
    return gain


def _as3d(x: np.ndarray) -> np.ndarray:
    """An image (n_z, n_x) or (n_z, n_y, n_x) as a 3-D view (n_z, 1, n_x) / itself."""
    return x.reshape(x.shape[0], 1, x.shape[1]) if x.ndim == 2 else x


def _dual_axes(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The z, y, x components of a dual field (d, *image shape) as 3-D views; in 2-D the y
    component is a placeholder the kernels never touch."""
    if q.shape[0] == 2:
        return _as3d(q[0]), np.zeros((1, 1, 1), dtype=q.dtype), _as3d(q[1])
    return q[0], q[1], q[2]


@numba.njit(cache=True, fastmath=True)
def _transpose_row(qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, z: int, y: int,
                   o: np.ndarray) -> None:
    """Row y of plane z of ∇ᵀq into ``o`` (n_x), in passes without a branch inside (SIMD)."""
    nz, ny, nx = qz.shape
    if z < nz - 1:
        row = qz[z, y]
        for x in range(nx):
            o[x] = -row[x]
    else:
        o[:] = 0.0
    if z > 0:
        row = qz[z - 1, y]
        for x in range(nx):
            o[x] += row[x]
    if has_y:
        if y < ny - 1:
            row = qy[z, y]
            for x in range(nx):
                o[x] -= row[x]
        if y > 0:
            row = qy[z, y - 1]
            for x in range(nx):
                o[x] += row[x]
    row = qx[z, y]
    for x in range(nx - 1):
        o[x] -= row[x]
    for x in range(1, nx):
        o[x] += row[x - 1]


@numba.njit(cache=True, fastmath=True)
def _primal_plane(v: np.ndarray, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, gamma: float,
                  positivity: bool, support: np.ndarray, use_support: bool, z: int, out: np.ndarray,
                  o: np.ndarray) -> None:
    """Plane z of `_prox_primal` into the 2-D ``out`` (n_y, n_x), row by row: ∇ᵀq into the
    row ``o`` (n_x, `_transpose_row`), then the projection into ``out`` (which may be v's
    plane z)."""
    ny, nx = out.shape
    for y in range(ny):
        _transpose_row(qz, qy, qx, has_y, z, y, o)
        vr = v[z, y]
        r = out[y]
        for x in range(nx):
            r[x] = vr[x] - gamma * o[x]
        if positivity:
            for x in range(nx):
                r[x] = max(r[x], 0.0)
        if use_support:
            sr = support[z, y]
            for x in range(nx):
                if not sr[x]:
                    r[x] = 0.0


@numba.njit(parallel=True, cache=True)
def _prox_primal(v: np.ndarray, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, gamma: float,
                 positivity: bool, support: np.ndarray, use_support: bool, out: np.ndarray) -> None:
    """The primal step ``out`` = P(v − γ ∇ᵀq) voxel by voxel (`_primal_plane` per plane), ∇ᵀ
    the transpose of the forward differences (0 at the last index): (∇ᵀq)_i = Σ_a
    [i_a < n_a − 1] (−q_a)_i + [i_a > 0] (q_a)_{i − e_a}; P clips below 0 (``positivity``)
    and zeroes off ``support`` (``use_support``). ``out`` may be ``v``: each voxel reads only
    its own v."""
    for z in numba.prange(v.shape[0]):
        o = np.empty(v.shape[2], dtype=out.dtype)
        _primal_plane(v, qz, qy, qx, has_y, gamma, positivity, support, use_support, z, out[z], o)


@numba.njit(cache=True, fastmath=True)
def _dual_row(a_diff: np.ndarray, b_diff: np.ndarray, e_diff: np.ndarray, qz: np.ndarray, qy: np.ndarray,
              qx: np.ndarray, has_y: bool, step: float, n: int) -> None:
    """One row of the dual step from the rows of w's differences along z, y, x (a zero row
    where the difference is 0): q ← (q + step ∇w) / max(1, |·|), in place; a loop without
    branches (SIMD)."""
    for x in range(n):
        a = qz[x] + step * a_diff[x]
        b = qy[x] + step * b_diff[x] if has_y else 0.0
        e = qx[x] + step * e_diff[x]
        inv = 1.0 / max(1.0, math.sqrt(a * a + b * b + e * e))
        qz[x] = a * inv
        qx[x] = e * inv
        if has_y:
            qy[x] = b * inv


@numba.njit(cache=True, fastmath=True)
def _dual_plane(cur: np.ndarray, nxt: np.ndarray, z: int, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray,
                has_y: bool, step: float, scratch: np.ndarray) -> None:
    """Plane z of the dual step (w's plane z ``cur``, plane z + 1 ``nxt``), row by row:
    ``scratch`` (>= 3, n_x) holds the row's differences of w along z, y and x."""
    nz = qz.shape[0]
    ny, nx = cur.shape
    dz, dy, dx = scratch[0], scratch[1], scratch[2]
    for y in range(ny):
        c = cur[y]
        if z < nz - 1:
            nr = nxt[y]
            for x in range(nx):
                dz[x] = nr[x] - c[x]
        else:
            dz[:] = 0.0
        if has_y and y < ny - 1:
            cy = cur[y + 1]
            for x in range(nx):
                dy[x] = cy[x] - c[x]
        else:
            dy[:] = 0.0
        for x in range(nx - 1):
            dx[x] = c[x + 1] - c[x]
        dx[nx - 1] = 0.0
        # in 2-D qy is a (1, 1, 1) placeholder `_dual_row` never touches
        _dual_row(dz, dy, dx, qz[z, y], qy[z, y] if has_y else qy[0, 0], qx[z, y], has_y, step, nx)


@numba.njit(parallel=True, cache=True)
def _prox_step(v: np.ndarray, qz: np.ndarray, qy: np.ndarray, qx: np.ndarray, has_y: bool, gamma: float,
               positivity: bool, support: np.ndarray, use_support: bool, step: float, starts: np.ndarray,
               planes: np.ndarray, rows: np.ndarray) -> None:
    """One inner step of the dual gradient projection in one sweep, q updated in place: w =
    P(v − γ ∇ᵀq) plane by plane, each plane of w made just before the dual step of the plane
    above it needs it (from q not yet stepped there), then q ← the projected step (`_dual_plane`). The
    volume's planes split into slabs [starts[k], starts[k + 1]) swept in parallel; ``planes``
    (n_slabs, 3, n_y, n_x) holds w at each slab's first plane, made from the old q before any
    slab steps, and each slab's two-plane ring; ``rows`` (n_slabs, 4, n_x) its scratch rows.
    The same arithmetic as a full primal sweep followed by a full dual sweep, without the
    image w: one pass over v and q."""
    nz = v.shape[0]
    n_slabs = starts.shape[0] - 1
    for k in numba.prange(n_slabs):
        _primal_plane(v, qz, qy, qx, has_y, gamma, positivity, support, use_support, starts[k], planes[k, 0],
                      rows[k, 3])
    for k in numba.prange(n_slabs):
        z0 = starts[k]
        z1 = starts[k + 1]
        cur = planes[k, 0]
        ring = 1
        for z in range(z0, z1):
            if z + 1 < z1:
                nxt = planes[k, ring]
                _primal_plane(v, qz, qy, qx, has_y, gamma, positivity, support, use_support, z + 1, nxt, rows[k, 3])
            elif z + 1 < nz:
                nxt = planes[k + 1, 0]
            else:
                nxt = cur  # the last plane: no difference along z
            _dual_plane(cur, nxt, z, qz, qy, qx, has_y, step, rows[k])
            cur = nxt
            ring = 3 - ring


@numba.njit(parallel=True, cache=True)
def _tv_norm_kernel(x: np.ndarray) -> float:
    """Σ_voxels sqrt(Σ_a (forward difference along a)²) of a 3-D array, the differences in
    x's dtype (as the proximal map sees them), the sum in float64."""
    nz, ny, nx = x.shape
    total = 0.0
    for z in numba.prange(nz):
        row = 0.0
        for y in range(ny):
            for i in range(nx):
                c = x[z, y, i]
                d0 = np.float64(x[z + 1, y, i] - c) if z < nz - 1 else 0.0
                d1 = np.float64(x[z, y + 1, i] - c) if y < ny - 1 else 0.0
                d2 = np.float64(x[z, y, i + 1] - c) if i < nx - 1 else 0.0
                row += math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        total += row
    return total


def _tv_norm(x: np.ndarray) -> float:
    """TV(x) = Σ_voxels |∇x|₂ (forward differences, voxel units), in float64; no work array."""
    return float(_tv_norm_kernel(_as3d(np.ascontiguousarray(x))))


def _tv_prox(v: np.ndarray, gamma: float, positivity: bool, support: np.ndarray | None, dual: np.ndarray | None,
             poll: Callable[[], None] | None = None,
             in_place: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """argmin_x ½‖x − v‖² + γ TV(x) over x >= 0 (positivity) and x = 0 off ``support``
    (None: everywhere allowed): gradient projection on the dual (Chambolle 2005; Beck &
    Teboulle 2009's GP), `_PROX_ITER` steps from ``dual`` (the previous call's, a warm start,
    updated in place; None: 0). No operator. ``poll()``, if given, is called every few inner
    steps (a cancel). Returns (x, dual); x is ``v`` (C-contiguous), overwritten, with
    ``in_place`` (the default), else a new array (v is kept). Each inner step is one compiled
    sweep over the volume (`_prox_step`; the primal w lives a few planes at a time), the dual
    stepped in place: no work image beyond the dual itself (d images, made when ``dual`` is
    None)."""
    if gamma <= 0:
        return _project(v if in_place else v.copy(), positivity, support), dual
    v = np.ascontiguousarray(v)  # the kernels see it through 3-D views
    q = np.zeros((v.ndim,) + v.shape, dtype=v.dtype) if dual is None else dual
    _dual_steps(v, q, float(gamma), positivity, support, poll)
    x = v if in_place else np.empty_like(v)
    _prox_primal(_as3d(v), *_dual_axes(q), v.ndim == 3, float(gamma), positivity, *_support3(support), _as3d(x))
    return x, q


def _tv_prox_stored(v: np.ndarray, gamma: float, positivity: bool, support: np.ndarray | None,
                    stored: list[np.ndarray | None],
                    poll: Callable[[], None] | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """`_tv_prox` (not in place: v is kept) with its dual kept between calls in half the
    working precision's bytes (`_store_dual`). ``stored`` is a list holding the last call's
    stored dual (None: 0), taken out of it: it is restored, freed, stepped, stored anew and
    freed again before the new iterate is made, whose final primal step reads the stored
    dual (the map is linear in it: γ ∇ᵀ(s / 32767) = (γ / 32767) ∇ᵀ s). So the full-precision
    dual (d images) and the new iterate are never held together, nor the old and the new
    stored dual: d + d/2 images at most beside v, where `_tv_prox` and `_store_dual` held
    d + d/2 + 1 (the paper's scan: tv's peak 9.3 -> 8.4 images, now inside the operator). Returns (x, the new
    stored dual); at γ <= 0 the projection of v and the stored dual unchanged."""
    old = stored.pop()
    if gamma <= 0:
        return _project(v.copy(), positivity, support), old
    v = np.ascontiguousarray(v)
    q = np.zeros((v.ndim,) + v.shape, dtype=v.dtype) if old is None else _restore_dual(old, v.dtype)
    del old
    _dual_steps(v, q, float(gamma), positivity, support, poll)
    kept = _store_dual(q)
    del q
    x = np.empty_like(v)
    scale = 1.0 / _DUAL_SCALE if kept.dtype == np.int16 else 1.0
    _prox_primal(_as3d(v), *_dual_axes(kept), v.ndim == 3, float(gamma) * scale, positivity, *_support3(support),
                 _as3d(x))
    return x, kept


def _project(x: np.ndarray, positivity: bool, support: np.ndarray | None) -> np.ndarray:
    """The image ``x`` clipped below 0 (``positivity``) and zeroed off ``support``, in place."""
    if positivity:
        np.maximum(x, 0, out=x)
    if support is not None:
        x[~support] = 0
    return x


def _support3(support: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """The kernels' (support as a 3-D bool array, whether there is one): a placeholder when None."""
    if support is None:
        return np.zeros((1, 1, 1), bool), False
    return _as3d(np.ascontiguousarray(support, dtype=bool)), True


def _dual_steps(v: np.ndarray, q: np.ndarray, gamma: float, positivity: bool, support: np.ndarray | None,
                poll: Callable[[], None] | None) -> None:
    """`_PROX_ITER` inner steps of `_tv_prox`'s dual gradient projection on ``q`` (d, *v.shape),
    in place: w = P(v − γ ∇ᵀq); q ← (q + step ∇w) / max(1, |·|), step = 1 / (γ ‖∇‖²)."""
    supp, has_support = _support3(support)
    has_y = v.ndim == 3
    v3 = _as3d(v)
    n_slabs = max(1, min(v3.shape[0], 2 * numba.get_num_threads()))
    starts = np.linspace(0, v3.shape[0], n_slabs + 1).astype(np.int64)
    planes = np.empty((n_slabs, 3) + v3.shape[1:], dtype=v.dtype)  # w's first plane and a ring of two
    rows = np.empty((n_slabs, 4, v3.shape[2]), dtype=v.dtype)  # each slab's rows: w's differences, ∇ᵀq
    step = 1.0 / (4.0 * v.ndim * gamma)  # 1 / (γ ‖∇‖²), ‖∇‖² <= 4 d
    for i in range(_PROX_ITER):
        if poll is not None and i % 5 == 4:
            poll()
        _prox_step(v3, *_dual_axes(q), has_y, gamma, positivity, supp, has_support, step, starts, planes, rows)


def _fista(forward: Callable[[np.ndarray], np.ndarray], G: Callable[[np.ndarray], np.ndarray], g: np.ndarray,
           start: list[np.ndarray], lam: float | Callable[[float], float], L: float, positivity: bool,
           max_iter: int, tol: float, started: float, time_limit: float, report: _Reporter | None,
           residual: Callable[[np.ndarray], float], support: np.ndarray | None = None,
           poll: Callable[[], None] | None = None, continuation: _Continuation | None = None,
           ) -> tuple[np.ndarray, int, str, float, np.ndarray, float, float]:
    """Accelerated proximal gradient (FISTA, Beck & Teboulle 2009) on J(p) = ½‖A p − g‖² +
    λ TV(p) (p >= 0 with ``positivity``; p = 0 off ``support`` when given), preconditioned:
    the step is G(A y − g) / L with G = B = P Aᵀ of a residual (module doc); the proximal
    map `_tv_prox`.

    One forward A (of the new iterate; A y follows by linearity) and one G per iteration.
    ``residual(Ax)`` = ‖A x − g‖, so J(x_k) is exact and free; ``poll`` as `_tv_prox`. Momentum:
    the constant `_MOMENTUM` (module doc), 0 for one step (a restart, O'Donoghue & Candès 2015)
    when J rises or the momentum points uphill. Stopping rule: the iterate's relative
    change ‖x_k − x_{k−1}‖ / ‖x_k‖ below ``tol`` in each of the last `_WINDOW` iterations
    ("converged"); else ``max_iter`` iterations ("iterations") or the time limit ("time
    limit"). L rises to `_MARGIN` × the gain of BA along the last move of y (free: a
    lower bound of ‖BA‖) when that exceeds it. ``lam`` is λ, or a rule λ(‖A x₀ − g‖) of the
    start's residual (the automatic λ: free, A x₀ is the first forward). With ``continuation``
    the proximal step and the restart test take λ_k = λ · ``continuation.factor(k)``, started
    from the same residual, and the stopping rule waits for λ itself (`_Continuation`). Returns (x,
    iterations, stop reason, the rule's last value, A x, L, λ). ``forward(v)`` = A v in the
    data's shape; ``start`` is a list holding the first x, which is taken out of it (its
    memory is reused: the caller keeps no reference).

    Memory (the proximal map's dual is d = 2 or 3 images, kept between calls at half the
    working precision's bytes, `_store_dual`: |dual| <= 1, so a float32 warm start keeps
    1.5e-5; the last G(A y − g), which only the next iteration's gain reads, and the last
    move b = x − x_prev wait as 16-bit fixed point, `_store_gradient` and `_store_move`:
    half a float32 image each; x itself is y − β q round(b / q), read back where it is
    needed): while A works, 1 image (the new iterate, which becomes y in its own place), d/2
    and the two halves; while G works, the same with y; while the proximal map works, 2 (the
    gradient step made in y's place, G(A y − g)), the move's half and d + d/2 at most (its
    dual at full precision beside the stored one), then one more for the new iterate, made
    from the stored dual once the full one is freed (`_tv_prox_stored`). At the paper's size
    (d = 3) that is 7 images in the proximal map and 3 beside the operator's k-space (about 3
    images there). Everything that needs y or x after y's gradient step (the restart test,
    ‖y_new − y‖ for the gain for both momenta y_new can take, the new move) is summed before
    A works, with y = the step + G(A y − g) / L (`_moves`), so y's memory is free
    then. The vectors are C-contiguous: the in-place kernels see them through flat views."""
    x = np.ascontiguousarray(start.pop())
    if support is not None:
        x = np.where(support, x, 0).astype(x.dtype)
    iterations = span(report, 0.1, 1.0)
    Ax = forward(x)
    r0 = residual(Ax)
    if callable(lam):  # λ from the start's residual ‖A x − g‖ (the automatic λ's rule)
        lam = float(lam(r0))
    if continuation is not None:  # λ_k from λ D₀ down to λ (`_Continuation`)
        continuation.start(r0, lam, max_iter)
    # y's memory takes the gradient step; x itself is not kept: x = y − β q b, with b the last
    # move x − x_prev as int16 and β q its scale (`_store_move`), which is how y was made
    y, Ay = x, Ax
    del x
    move: tuple[np.ndarray, float] = (np.zeros(y.size, dtype=np.int16), 0.0)  # the start: x = y
    # G(A y − g) of the last y, kept as 16-bit fixed point with its quantum (`_store_gradient`), and ‖y − last y‖
    G_prev: tuple[np.ndarray, float] | None = None
    dy = 0.0

    def parts(Ax_: np.ndarray, x_: np.ndarray) -> tuple[float, float]:  # J's data term and TV(x)
        return 0.5 * residual(Ax_) ** 2, (_tv_norm(x_) if lam > 0 else 0.0)

    J_prev = parts(Ax, y)  # the restart test's, at each iteration's λ_k
    steps: deque[float] = deque(maxlen=_WINDOW)  # ‖x_k − x_{k−1}‖ / ‖x_k‖ of the last iterations
    stored = None  # the proximal map's dual between calls, in half the bytes (`_store_dual`)
    change, it, stop_reason = float("nan"), 0, "iterations"
    xn = y  # for max_iter = 0, which the callers never ask
    for it in range(1, max_iter + 1):
        lam_k = lam * continuation.factor(it) if continuation is not None else lam
        Gy = G(np.subtract(Ay, g, dtype=Ay.dtype))  # the residual in the working dtype (B's input)
        if G_prev is not None and dy > 0:  # the gain of BA along the last move of y: a lower bound of ‖BA‖
            gain = _gain_lower_bound(Gy.ravel(), G_prev) / dy
            if _MARGIN * gain > L:  # the step was too long for what the iterates excite
                L = _MARGIN * gain
        G_prev = None
        v = y  # the gradient step y − G(A y − g) / L, in y's place (y = v + Gy / L from here on)
        del y, xn
        _axpy(v.ravel(), Gy.ravel(), -1.0 / L)
        box: list[np.ndarray | None] = [stored]  # handed over: freed inside once restored
        stored = None
        xn, stored = _tv_prox_stored(v, lam_k / L, positivity, support, box, poll)  # None at λ = 0 (no dual)
        # a = x_new − y, b = x_new − x: the restart test ⟨a, b⟩ < 0 and ‖y_new − y‖ = ‖a + β b‖
        # for β = 0 and `_MOMENTUM`, now, so that y (v) is free while A works; b kept as int16
        ab, aa, cc, bb, nn, b_max = _moves(xn.ravel(), v.ravel(), Gy.ravel(), 1.0 / L, move[0], move[1], _MOMENTUM)
        b_new = _store_move(xn.ravel(), v.ravel(), Gy.ravel(), 1.0 / L, move[0], move[1], b_max)
        del v, move
        G_prev = _store_gradient(Gy)  # for the next gain, in half (float64: a quarter) of the bytes
        del Gy
        Axn = forward(xn)
        J = parts(Axn, xn)
        # constant momentum, restarted (β = 0) when J (at this iteration's λ_k) rises or the momentum points uphill
        beta = 0.0 if J[0] + lam_k * J[1] > J_prev[0] + lam_k * J_prev[1] or ab < 0 else _MOMENTUM
        dy = math.sqrt(cc if beta else aa)
        Ay = Axn + beta * (Axn - Ax)
        Ax = Axn
        J_prev = J
        steps.append(math.sqrt(bb / nn) if nn > 0 else (0.0 if bb == 0 else math.inf))
        if len(steps) == _WINDOW:
            change = max(steps)
        elapsed = time.monotonic() - started
        if iterations is not None:
            # the stage "iteration k/N" carries the stopping rule's value (its window so far) and tol,
            # not yet armed while λ still falls (the rule cannot stop the run there)
            waiting = continuation is not None and not continuation.window_at_lambda(it) and tol > 0
            iterations(max(it / max_iter, elapsed / time_limit),
                       IterationStage(it, max_iter, max(steps), tol, armed=not waiting))
        # the rule's window holds iterations at λ itself only (none of the continuation's)
        if 0.0 <= change < tol and (continuation is None or continuation.window_at_lambda(it)):
            stop_reason = "converged"
            break
        if elapsed >= time_limit and it < max_iter:
            stop_reason = "time limit"
            break
        if it == max_iter:
            break
        # y_new = x_new + β b in x_new's place (the result is x_new itself: made only when going on)
        move = (b_new[0], beta * b_new[1])
        del b_new
        _extrapolate_fixed(xn.ravel(), move[0], move[1])
        y = xn  # noqa: F841 (read at the loop's top: ruff does not follow the loop past the del there)
    return xn, it, stop_reason, float(change), Ax, L, lam


class _GeometryMemo:
    """The last few geometries' ‖BA‖ estimate and noise-image RMS (`reconstruct_tv`): numbers
    of the operator, the preconditioner and the seeded starts alone, so a repeated scan plan
    (the same mask, grid, sampling and band) skips the 2.5 operator pairs that make them, and
    its result is the one a fresh process computes. At most `_GEOMETRY_KEPT` entries (a few
    floats each), the oldest dropped first; safe across threads."""

    def __init__(self, size: int) -> None:
        import threading

        self._size, self._lock = size, threading.Lock()
        self._items: dict[tuple, tuple[float, float]] = {}

    def get(self, key: tuple) -> tuple[float, float] | None:
        with self._lock:
            value = self._items.pop(key, None)
            if value is not None:
                self._items[key] = value  # most recent last
            return value

    def put(self, key: tuple, value: tuple[float, float]) -> None:
        with self._lock:
            self._items.pop(key, None)
            self._items[key] = value
            while len(self._items) > self._size:
                self._items.pop(next(iter(self._items)))

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


#: geometries kept (`_GeometryMemo`): a lab alternates between a few scan plans
_GEOMETRY_KEPT = 8
_GEOMETRY = _GeometryMemo(_GEOMETRY_KEPT)


def _geometry_key(op: PlanarOperator, shape: tuple[int, ...], dx: float, dz: float, pos: np.ndarray | None,
                  rdtype: npt.DTypeLike, data_shape: tuple[int, ...]) -> tuple:
    """What ‖BA‖ and the noise image depend on: the operator's grid, sampling, band, sensors
    (their bytes' digest), precision and the data's shape (the noise record's)."""
    import hashlib

    where = None if pos is None else hashlib.sha256(np.ascontiguousarray(pos, dtype=np.float64).tobytes()).hexdigest()
    return (tuple(shape), float(dx), float(dz), float(op.dt), int(op.n_t), float(op.c), float(op.t0), float(op.eps),
            op.band, bool(op.periodic), op.padded_shape, np.dtype(rdtype).name, tuple(data_shape), where)


class _DiscrepancyRule:
    """The automatic λ as a rule of the warm start's residual r₀ = ‖A x₀ − g‖ (module doc):
    ``rule(r₀)`` = s · `_LAM_SCALE` · max(1, (D₀ / `_LAM_KNEE`) ** `_LAM_POWER`), D₀ = r₀ / (σ̂ √N),
    for the image's noise level s and the noise's norm σ̂ √N. After the call ``factor`` is
    λ / s and ``warm_discrepancy`` D₀ (None while unknown, or without a noise estimate: then
    the factor is `_LAM_SCALE`)."""

    def __init__(self, image_noise: float, noise_norm: float):
        self.image_noise, self.noise_norm = image_noise, noise_norm
        self.factor: float = _LAM_SCALE
        self.warm_discrepancy: float | None = None

    def __call__(self, start_residual: float) -> float:
        d0 = start_residual / self.noise_norm if self.noise_norm > 0 else math.inf
        if math.isfinite(d0):
            self.warm_discrepancy, self.factor = d0, _LAM_SCALE * max(1.0, (d0 / _LAM_KNEE) ** _LAM_POWER)
        return self.image_noise * self.factor


class _Continuation:
    """λ continuation (module doc, "Continuation"): iteration k proximal-steps with λ_k = λ ·
    max(1, f₀ · `_CONTINUATION_RATE` ** (k − 1)), from f₀ = D₀ = ‖A x₀ − g‖ / (σ̂ √N) (the
    warm start's discrepancy in noise norms, at least 1) down to λ, in at most half of
    ``max_iter`` iterations (f₀ is capped there). ``start(r₀, λ, max_iter)`` sets ``start_factor``
    (f₀) and ``iterations`` (how many iterations have λ_k > λ); without a noise estimate (σ̂ =
    0) or at λ = 0 there is none (f₀ = 1)."""

    def __init__(self, noise_norm: float):
        self.noise_norm = noise_norm
        self.start_factor, self.iterations = 1.0, 0

    def start(self, start_residual: float, lam: float, max_iter: int) -> None:
        d0 = start_residual / self.noise_norm if self.noise_norm > 0 else 1.0
        if not (lam > 0 and math.isfinite(d0) and d0 > 1):
            self.start_factor, self.iterations = 1.0, 0
            return
        # in logs: the cap r^−(max_iter // 2) overflows a float for the largest max_iter
        self.start_factor = math.exp(min(math.log(d0), (max_iter // 2) * -math.log(_CONTINUATION_RATE)))
        # iterations k with f₀ r^(k−1) > 1
        self.iterations = (math.ceil(math.log(self.start_factor) / -math.log(_CONTINUATION_RATE))
                           if self.start_factor > 1 else 0)

    def factor(self, k: int) -> float:
        return max(1.0, self.start_factor * _CONTINUATION_RATE ** (k - 1))

    def window_at_lambda(self, k: int) -> bool:
        """Whether the stopping rule's window at iteration k holds iterations at λ only (always,
        where λ does not fall)."""
        return self.iterations == 0 or k - self.iterations >= _WINDOW


#: the fixed-point scale of a float32 dual between calls (`_store_dual`)
_DUAL_SCALE = 32767.0


def _store_dual(dual: np.ndarray) -> np.ndarray:
    """The proximal map's dual (C-contiguous, |components| <= 1) at half the working
    precision's bytes, for the wait between iterations (`_fista`): float32 -> int16 fixed
    point, round(q · 32767) (error <= 1.5e-5, where float16 kept 2⁻¹¹ near 1); float64 ->
    float32. By compiled parallel loops: numpy's float16 casts took 0.06-0.08 s a call on
    the three images of a 512 × 128² volume, 3 s of tv's 30 s there."""
    if dual.dtype == np.float32:
        out = np.empty(dual.shape, dtype=np.int16)
        _quantise(dual.reshape(-1), out.reshape(-1), _DUAL_SCALE)
    else:
        out = np.empty(dual.shape, dtype=np.float32)
        _cast(dual.reshape(-1), out.reshape(-1))
    return out


def _store_gradient(g: np.ndarray) -> tuple[np.ndarray, float]:
    """A preconditioned gradient G(A y − g) kept for the next iteration's gain (`_fista`) as
    16-bit fixed point: (round(g / q), q) with the quantum q = max |g| / 32767, so that each
    value is off by at most q / 2 (`_gain_lower_bound` subtracts that)."""
    flat = g.reshape(-1)
    top = _max_abs(flat)
    quantum = top / _DUAL_SCALE if top > 0 else 1.0
    out = np.empty(flat.shape, dtype=np.int16)
    _quantise(flat, out, 1.0 / quantum)
    return out, quantum


def _gain_lower_bound(g: np.ndarray, stored: tuple[np.ndarray, float]) -> float:
    """‖g − g_prev‖ from below, with g_prev kept by `_store_gradient`: the distance to the
    fixed-point values less the largest their rounding can move it, q √N / 2 (‖e‖ for
    |e_i| <= q / 2; with 1e-6 of it for the float64 sums), so that the solver's L rises only
    where ‖BA‖ really exceeds it."""
    values, quantum = stored
    measured = _difference_norm_fixed(g, values, quantum)
    return max(0.0, measured - 0.5 * quantum * math.sqrt(g.size) * (1.0 + 1e-6))


@numba.njit(parallel=True, cache=True)
def _max_abs(a: np.ndarray) -> float:
    """The largest |a_i| of a flat array (0 for an empty one), in float64."""
    top = 0.0
    for i in numba.prange(a.size):
        top = max(top, abs(np.float64(a[i])))
    return top


@numba.njit(parallel=True, cache=True)
def _difference_norm_fixed(a: np.ndarray, s: np.ndarray, quantum: float) -> float:
    """‖a − s · quantum‖₂ of a flat array and fixed-point values ``s``, summed in float64."""
    total = 0.0
    for i in numba.prange(a.size):
        d = np.float64(a[i]) - np.float64(s[i]) * quantum
        total += d * d
    return math.sqrt(total)


def _restore_dual(stored: np.ndarray, dtype: npt.DTypeLike) -> np.ndarray:
    """`_store_dual` undone: a new array of ``dtype`` (float32 from int16, float64 from float32)."""
    out = np.empty(stored.shape, dtype=dtype)
    if stored.dtype == np.int16:
        _dequantise(stored.reshape(-1), out.reshape(-1), 1.0 / _DUAL_SCALE)
    else:
        _cast(stored.reshape(-1), out.reshape(-1))
    return out


@numba.njit(parallel=True, cache=True)
def _quantise(q: np.ndarray, out: np.ndarray, scale: float) -> None:
    """Fixed point: out = round(clip(q · scale, -32767, 32767)) (flat arrays; ``out`` int16)."""
    for i in numba.prange(q.size):
        out[i] = math.floor(min(max(q[i] * scale, -32767.0), 32767.0) + 0.5)


@numba.njit(parallel=True, cache=True)
def _dequantise(s: np.ndarray, out: np.ndarray, inv_scale: float) -> None:
    """Fixed point undone: out = s · inv_scale (flat arrays)."""
    for i in numba.prange(s.size):
        out[i] = s[i] * inv_scale


@numba.njit(parallel=True, cache=True)
def _cast(src: np.ndarray, out: np.ndarray) -> None:
    """A parallel copy: out = src, converted to ``out``'s dtype (flat arrays)."""
    for i in numba.prange(src.size):
        out[i] = src[i]


@numba.njit(parallel=True, cache=True)
def _difference_norm(a: np.ndarray, b: np.ndarray) -> float:
    """‖a − b‖₂ of two flat arrays, summed in float64 (no work array)."""
    total = 0.0
    for i in numba.prange(a.size):
        d = np.float64(a[i]) - np.float64(b[i])
        total += d * d
    return math.sqrt(total)


@numba.njit(parallel=True, cache=True)
def _axpy(y: np.ndarray, x: np.ndarray, s: float) -> None:
    """In place, y += s x (flat arrays of one dtype)."""
    for i in numba.prange(y.size):
        y[i] += s * x[i]


def _store_move(xn: np.ndarray, v: np.ndarray, gy: np.ndarray, inv_l: float, b_last: np.ndarray,
                scale_last: float, b_max: float) -> tuple[np.ndarray, float]:
    """The move b = x_new − x (flat arrays; x = v + inv_l gy − scale_last b_last as `_moves`) as
    16-bit fixed point: (round(b / q), q) with q = ``b_max`` / 32767 (``b_max`` = max |b|, from
    `_moves`). y = x_new + β q round(b / q) then differs from the exact extrapolation by at
    most β q / 2 a voxel, and x = y − β q round(b / q) is exact (to the working precision's
    rounding), which is all the solver needs of x."""
    quantum = b_max / _DUAL_SCALE if b_max > 0 else 0.0
    out = np.empty(xn.shape, dtype=np.int16)
    _quantise_move(xn, v, gy, inv_l, b_last, scale_last, 1.0 / quantum if quantum > 0 else 0.0, out)
    return out, quantum


@numba.njit(parallel=True, cache=True)
def _quantise_move(xn: np.ndarray, v: np.ndarray, gy: np.ndarray, inv_l: float, b_last: np.ndarray,
                   scale_last: float, mult: float, out: np.ndarray) -> None:
    """The move's fixed point: out = round(clip((x_new − x) · mult, ±32767)), with
    x = v + inv_l gy − scale_last b_last (flat arrays)."""
    for i in numba.prange(xn.size):
        x = np.float64(v[i]) + inv_l * np.float64(gy[i]) - scale_last * np.float64(b_last[i])
        out[i] = math.floor(min(max((np.float64(xn[i]) - x) * mult, -32767.0), 32767.0) + 0.5)


@numba.njit(parallel=True, cache=True)
def _extrapolate_fixed(xn: np.ndarray, b: np.ndarray, scale: float) -> None:
    """In place, xn ← xn + scale b (flat arrays, b int16): FISTA's next y = x_new + β q b in
    the new iterate's place."""
    for i in numba.prange(xn.size):
        xn[i] = xn[i] + scale * b[i]


@numba.njit(parallel=True, cache=True)
def _moves(xn: np.ndarray, v: np.ndarray, gy: np.ndarray, inv_l: float, b_last: np.ndarray, scale_last: float,
           beta: float) -> tuple[float, float, float, float, float, float]:
    """With y = v + inv_l gy (the gradient step v = y − gy / L undone) and x = y − scale_last
    b_last (y's extrapolation undone: `_store_move`), a = xn − y and b = xn − x (flat
    arrays): (⟨a, b⟩, ‖a‖², ‖a + β b‖², ‖b‖², ‖xn‖², max |b|), summed in float64."""
    ab = 0.0
    aa = 0.0
    cc = 0.0
    bb = 0.0
    nn = 0.0
    top = 0.0
    for i in numba.prange(xn.size):
        xi = np.float64(xn[i])
        yi = np.float64(v[i]) + inv_l * np.float64(gy[i])
        a = xi - yi
        b = xi - (yi - scale_last * np.float64(b_last[i]))
        c = a + beta * b
        ab += a * b
        aa += a * a
        cc += c * c
        bb += b * b
        nn += xi * xi
        top = max(top, abs(b))
    return ab, aa, cc, bb, nn, top


class _Reporter:
    """``report(fraction, stage)``: passes increasing fractions on to ``progress``;
    ``poll()``: the same fraction and stage again, at most every `_POLL_S` seconds, so that
    a ``progress`` that raises to cancel (the pipeline's ``should_stop``) is heard inside
    long steps too (the operator's checkpoints, the proximal map's inner iterations)."""

    def __init__(self, progress: Progress | None) -> None:
        self.progress = progress
        self.fraction, self.stage, self.at = 0.0, "warm start", time.monotonic()

    def __call__(self, f: float, stage: str) -> None:
        if self.progress is not None and f > self.fraction:
            self.fraction, self.stage, self.at = f, stage, time.monotonic()
            self.progress(f, stage)

    def poll(self) -> None:
        if self.progress is not None and time.monotonic() - self.at >= _POLL_S:
            self.at = time.monotonic()
            self.progress(self.fraction, self.stage)


def _reporter(progress: Progress | None) -> _Reporter:
    return _Reporter(progress)
