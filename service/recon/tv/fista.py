"""tv's solver loop: NER-preconditioned FISTA with a constant momentum and restarts, then steps
whose fixed point is J's minimiser.

Accelerated proximal gradient (FISTA, Beck & Teboulle 2009) on J(p) = ½‖A p − g‖² + λ TV(p),
p >= 0, preconditioned by NER: each iteration takes one forward A (of the new iterate; A y
follows by linearity) and one B = P Aᵀ of the residual (`fpscan.service.recon.tv.preconditioner`),
steps along B(A y − g) with step 1 / L, and applies the proximal map of λ_k TV + positivity
(`fpscan.service.recon.tv.prox`). L starts at `MARGIN` ‖BA‖ (`fpscan.service.recon.tv.geometry`) and is
raised to `MARGIN` × the gain of BA along the last move of the iterates whenever that
exceeds it (free: those products are computed anyway). Momentum: a constant β =
`MOMENTUM` (y_{k+1} = x_{k+1} + β (x_{k+1} − x_k)), set to 0 for one step (a restart) when J
rises or the momentum points uphill (O'Donoghue & Candès 2015): Nesterov's constant scheme
for a strongly convex objective, with the restarts standing in for the unknown condition
number. J(x) is exact and free (A x is computed anyway). The stopping rule:
`fpscan.service.recon.tv.stopping`; λ and its continuation: `fpscan.service.recon.tv.lam`; what waits
between iterations in 16 bits: `fpscan.service.recon.tv.stores`. `debias_refit` refits the amplitudes
at λ = 0 on tv's support. The measurements behind these choices: docs/tv-measurements.md,
"Solver" and "Memory".

Two phases. A fixed point of the preconditioned step x = prox_{λ/L}(x − P ∇f(x) / L), f(x) =
½‖A x − g‖², solves 0 ∈ P ∇f(x) + ∂(λ TV + positivity)(x), which is not J's minimiser unless
P = I: the Euclidean proximal map does not undo P. It is the fast phase (on k-Wave's vessel
tree at 11 % of the lattice, CC 0.989 after 30 iterations) and the default stopping rule ends
there. Once the image has settled at λ (its relative change below `SETTLED` in each of the last
3 iterations) a run asked to go on (``tol`` below `SETTLED`, or 0) continues with the exact
step: the gradient step takes G(A y − g) + L_s (P s − s), s = v − x_new of the last proximal
step (L_s s is then a subgradient of λ TV + positivity at x_new). Written in v, the iteration is
v ← v − (P / L) R, R = ∇f(x) + L (v − x) at x = prox(v), the residual of J's optimality
condition, so with P invertible its fixed points are exactly J's minimisers (the
forward-backward fixed points; a preconditioned residual step as in Themelis & Patrinos,
"SuperMann", IEEE Trans. Autom. Control 64 (2019) 4875); with P = I it is the preconditioned
step itself. One P more per iteration and s in 16 bits: on the vessel tree J falls 0.03 % below
pyproximal's tuned PrimalDual's after 300 iterations (docs/tv-measurements.md, "What tv
minimises").

The in-place vector loops here are numba kernels (``cache=True``; `fpscan.service.recon.methods.tv`'s
``kernel_modules``); the loop reaches them, and the other whole-image work, through the kernel set
of its arrays' type (`fpscan.service.recon.tv.kernels`: CuPy's on a GPU), so that the CPU and the GPU run
one loop.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np

from fpscan.physics.array_kernels import difference_norm
from fpscan.service.progress import span
from fpscan.service.recon.limits import DEFAULT_TOL
from fpscan.service.recon.tv.kernels import Kernels, array_kernels, array_module
from fpscan.service.recon.tv.lam import Continuation
from fpscan.service.recon.tv.progress import Reporter
from fpscan.service.recon.tv.prox import tv_norm, tv_prox_stored
from fpscan.service.recon.tv.stopping import StoppingRule
from fpscan.service.recon.tv.stores import extrapolate_fixed, gain_lower_bound, store_gradient, store_move

__all__ = ["MARGIN", "MOMENTUM", "SETTLED", "DEBIAS_ITER", "SUPPORT_FRACTION", "Solved", "run_fista", "debias_refit", "axpy", "moves", "difference_norm", "COMPILED", "kernels_for"]

#: the step is 1 / (MARGIN ‖BA‖), and L rises to MARGIN × a larger gain the iterates show
MARGIN = 1.1
#: the momentum β between restarts (constant: module doc)
MOMENTUM = 0.94
#: the image's relative change below which, in each of the last 3 iterations at λ, the preconditioned
#: phase has settled and the exact phase begins (`run_fista`): the default stopping threshold, so that a
#: run to the default rule ends where the preconditioned phase does
SETTLED = DEFAULT_TOL
#: iterations of the least-squares refit on the support (`debias_refit`)
DEBIAS_ITER = 10
#: the support of `debias_refit`: p0 above this share of its maximum
SUPPORT_FRACTION = 0.05


class Solved(NamedTuple):
    """What `run_fista` returns.

    Attributes
    ----------
    x : ndarray
        The image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)`` (Pa), in the working dtype.
    iterations : int
        The iterations run.
    stop_reason : str
        "converged", "iterations" or "time limit".
    change : float
        The stopping rule's last value (NaN before its window filled;
        `fpscan.service.recon.tv.stopping.StoppingRule`).
    Ax : ndarray
        A x, in the data's shape.
    L : float
        The step's L (1 / step) at the end.
    lam : float
        The λ used (the data's unit, Pa).
    exact_from : int or None
        The first iteration of the exact phase (`run_fista`; None: none ran).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.fista import Solved
    >>> s = Solved(np.zeros((2, 2)), 3, "iterations", 0.01, np.zeros(4), 1.1, 0.5)
    >>> s.iterations, s.stop_reason, s.lam
    (3, 'iterations', 0.5)
    """

    x: np.ndarray
    iterations: int
    stop_reason: str
    change: float
    Ax: np.ndarray
    L: float
    lam: float
    exact_from: int | None = None


def run_fista(forward: Callable[[np.ndarray], np.ndarray], G: Callable[[np.ndarray], np.ndarray], g: np.ndarray,
           start: list[np.ndarray], lam: float | Callable[[float], float], L: float, positivity: bool,
           max_iter: int, tol: float, started: float, time_limit: float, report: Reporter | None,
           residual: Callable[[np.ndarray], float], support: np.ndarray | None = None,
           poll: Callable[[], None] | None = None, continuation: Continuation | None = None,
           kernels: Kernels | None = None, callback: Callable[[int, np.ndarray, float], None] | None = None,
           precondition: Callable[[np.ndarray], np.ndarray] | None = None) -> Solved:
    """Accelerated proximal gradient (FISTA; Beck & Teboulle, SIAM J. Imaging Sci. 2 (2009) 183),
    preconditioned, on J(p) = ½‖A p − g‖² + λ TV(p) (p >= 0 with ``positivity``; p = 0 off
    ``support`` when given).

    The step is G(A y − g) / L with G = B = P Aᵀ of a residual (module doc); the proximal map
    `fpscan.service.recon.tv.prox.tv_prox_stored`. One forward A (of the new iterate; A y follows
    by linearity) and one G per iteration; ``residual(Ax)`` = ‖A x − g‖, so J(x_k) is exact and
    free. Momentum: the constant `MOMENTUM`, 0 for one step (a restart; O'Donoghue & Candès,
    Found. Comput. Math. 15 (2015) 715) when J rises or the momentum points uphill. Stopping rule
    (`fpscan.service.recon.tv.stopping`): the iterate's relative change ‖x_k − x_{k−1}‖ / ‖x_k‖
    below ``tol`` in each of the last 3 iterations ("converged"); else ``max_iter`` iterations
    ("iterations") or the time limit ("time limit"). L rises to `MARGIN` × the gain of BA along
    the last move of y (free: a lower bound of ‖BA‖) when that exceeds it. With ``continuation``
    the proximal step and the restart test take λ_k = λ · ``continuation.factor(k)``, started
    from the start's residual, and the stopping rule waits for λ itself.

    Memory (the proximal map's dual is d = 2 or 3 images, kept between calls at half the working
    precision's bytes; the last G(A y − g) and the last move b = x − x_prev wait as 16-bit fixed
    point, `fpscan.service.recon.tv.stores`; x itself is y − β q round(b / q), read back where it
    is needed): while A works, 1 image, d/2 and the two halves; while G works, the same with y;
    while the proximal map works, 2, the move's half and d + d/2 at most, then one more for the
    new iterate. At the paper's size (d = 3) that is 7 images in the proximal map and 3 beside
    the operator's k-space. The vectors are C-contiguous: the in-place kernels see them through
    flat views.

    Parameters
    ----------
    forward : callable
        ``forward(v)`` = A v in the data's shape (a new array), v an image.
    G : callable
        ``G(r)`` = P Aᵀ r as an image, r in the data's shape.
    g : ndarray
        The data (Pa), the working dtype's arrays' namespace (a GPU run's: CuPy).
    start : list
        One element, the first x (an image ``(n_z, n_x)`` / ``(n_z, n_y, n_x)``, float32 or
        float64), taken out of it: its memory is reused (the caller keeps no reference).
    lam : float or callable
        λ >= 0 (Pa), or a rule λ(‖A x₀ − g‖) of the start's residual (the automatic λ:
        `fpscan.service.recon.tv.lam.DiscrepancyRule`).
    L : float
        The first L (> 0): `MARGIN` ‖BA‖ (`fpscan.service.recon.tv.geometry`).
    positivity : bool
        Constrain p >= 0.
    max_iter : int
        Iterations at most (>= 1).
    tol : float
        The stopping rule's threshold (0: run ``max_iter``).
    started : float
        The run's start, `time.monotonic` (s).
    time_limit : float
        Wall-time limit from ``started``, s.
    report : Reporter or None
        The run's progress (`fpscan.service.recon.tv.progress.Reporter`): fractions 0.1 -> 1.
    residual : callable
        ``residual(Ax)`` = ‖A x − g‖ (float).
    support : ndarray of bool, optional
        The image's shape: p = 0 where False.
    poll : callable, optional
        Called inside long steps (a cancel may raise there).
    continuation : Continuation, optional
        λ's continuation (`fpscan.service.recon.tv.lam.Continuation`).
    kernels : Kernels, optional
        The whole-image kernel set (`fpscan.service.recon.tv.kernels`; default `kernels_for` the
        start's array type).
    callback : callable, optional
        ``callback(k, x, J)`` after iteration k with its iterate x (the solver's array, valid
        during the call only) and J(x) = ½‖A x − g‖² + λ TV(x) at λ itself (exact, free).
    precondition : callable, optional
        ``precondition(v)`` = P v for an image v (which it may overwrite), G's P: with it, a run
        with ``tol`` below `SETTLED` goes on into the exact phase once the image has settled
        (module doc), whose fixed points are J's minimisers; without it (or with ``tol`` >=
        `SETTLED`) every step is the preconditioned one.

    Returns
    -------
    Solved
        The image, iterations, stop reason, the rule's last value, A x, L, λ and the exact
        phase's first iteration.

    Examples
    --------
    Denoising (A = I, P = I) of a noisy step with positivity:

    >>> import time
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.fista import MARGIN, run_fista
    >>> g = np.array([[0.0, 0.1, -0.1, 1.0, 1.1, 0.9]])
    >>> s = run_fista(lambda v: v.copy(), lambda r: r, g, [g.copy()], 0.1, MARGIN, True, 20, 0.0,
    ...               time.monotonic(), 60.0, None, lambda Ax: float(np.linalg.norm(Ax - g)))
    >>> s.iterations, s.stop_reason, s.lam, bool(s.x.min() >= 0)
    (20, 'iterations', 0.1, True)
    >>> bool(np.abs(s.x - g).max() < 0.3)  # close to the data, its noise smoothed
    True
    """
    k = kernels or kernels_for(start[0])  # the compiled loops for NumPy arrays, CuPy's for a GPU run
    x = k.contiguous(start.pop())
    if support is not None:
        x = k.masked(x, support)
    iterations = span(report, 0.1, 1.0)
    Ax = forward(x)
    r0 = residual(Ax)
    floored = False  # the reach floor set λ (the automatic λ's rule says so): the ETA's typical stop is later
    if callable(lam):  # λ from the start's residual ‖A x − g‖ (the automatic λ's rule)
        rule = lam
        lam = float(rule(r0))
        floored = bool(getattr(rule, "floored", False))
    if continuation is not None:  # λ_k from λ D₀ down to λ (`Continuation`)
        continuation.start(r0, lam, max_iter)
    # y's memory takes the gradient step; x itself is not kept: x = y − β q b, with b the last
    # move x − x_prev as int16 and β q its scale (`store_move`), which is how y was made
    y, Ay = x, Ax
    del x
    move: tuple[np.ndarray, float] = (k.zeros_move(y.size), 0.0)  # the start: x = y
    # G(A y − g) of the last y, kept as 16-bit fixed point with its quantum (`store_gradient`), and ‖y − last y‖
    G_prev: tuple[np.ndarray, float] | None = None
    dy = 0.0

    def parts(Ax_: np.ndarray, x_: np.ndarray) -> tuple[float, float]:  # J's data term and TV(x)
        return 0.5 * residual(Ax_) ** 2, (k.tv_norm(x_) if lam > 0 else 0.0)

    J_prev = parts(Ax, y)  # the restart test's, at each iteration's λ_k
    # the stopping rule, whose window holds iterations at λ itself only (none of the continuation's)
    stopping = StoppingRule(tol, max_iter, time_limit, continuation.iterations if continuation is not None else 0,
                            floored)
    stored = None  # the proximal map's dual between calls, in half the bytes (`store_dual`)
    it, stop_reason = 0, "iterations"
    xn = y  # for max_iter = 0, which the callers never ask
    # the exact phase (with ``precondition``): from the iteration after the image has settled at λ, each
    # gradient step adds L_s (P s − s), s = v − x_new of the last proximal step kept as int16 with its
    # quantum and that step's L (`store_gradient`'s form), so that a fixed point is J's minimiser
    exact_from: int | None = None
    kept: tuple[np.ndarray, float, float] | None = None
    for it in range(1, max_iter + 1):
        lam_k = lam * continuation.factor(it) if continuation is not None else lam
        Gy = G(k.subtract(Ay, g))  # the residual in the working dtype (B's input)
        if G_prev is not None and dy > 0:  # the gain of BA along the last move of y: a lower bound of ‖BA‖
            gain = k.gain_lower_bound(Gy.ravel(), G_prev) / dy
            if MARGIN * gain > L:  # the step was too long for what the iterates excite
                L = MARGIN * gain
        G_prev = None
        G_pure = None
        if kept is not None:  # the exact phase's step: Gy + L_s (P s − s)
            assert precondition is not None
            G_pure = k.store_gradient(Gy)  # the next gain test's: G(A y − g) itself
            values, quantum, L_s = kept
            kept = None
            s_img = array_module(Gy).zeros_like(Gy)
            k.extrapolate_fixed(s_img.ravel(), values, quantum)  # s, read back
            del values
            k.axpy(Gy.ravel(), s_img.ravel(), -L_s)
            s_img = precondition(s_img)  # P s (in s's place where the transform allows)
            k.axpy(Gy.ravel(), s_img.ravel(), L_s)
            del s_img
        v = y  # the gradient step y − G(A y − g) / L, in y's place (y = v + Gy / L from here on)
        del y, xn
        k.axpy(v.ravel(), Gy.ravel(), -1.0 / L)
        box: list[np.ndarray | None] = [stored]  # handed over: freed inside once restored
        stored = None
        xn, stored = k.tv_prox_stored(v, lam_k / L, positivity, support, box, poll)  # None at λ = 0 (no dual)
        # a = x_new − y, b = x_new − x: the restart test ⟨a, b⟩ < 0 and ‖y_new − y‖ = ‖a + β b‖
        # for β = 0 and `MOMENTUM`, now, so that y (v) is free while A works; b kept as int16
        ab, aa, cc, bb, nn, b_max = k.moves(xn.ravel(), v.ravel(), Gy.ravel(), 1.0 / L, move[0], move[1], MOMENTUM)
        b_new = k.store_move(xn.ravel(), v.ravel(), Gy.ravel(), 1.0 / L, move[0], move[1], b_max)
        stopping.observe(bb, nn)
        if (exact_from is None and precondition is not None and stopping.tol < SETTLED
                and 0.0 <= stopping.change < SETTLED and stopping.at_lambda(it)):
            exact_from = it + 1  # settled: the exact phase from the next iteration on
        if exact_from is not None:  # s = v − x_new (L s is in ∂(λ_k TV + positivity)(x_new)), for the next step
            s_new = k.subtract(v, xn)
            values, quantum = k.store_gradient(s_new)
            kept = (values, quantum, L)
            del s_new, values
        del v, move
        # for the next gain, in half (float64: a quarter) of the bytes
        G_prev = G_pure if G_pure is not None else k.store_gradient(Gy)
        del Gy, G_pure
        Axn = forward(xn)
        J = parts(Axn, xn)
        if callback is not None:
            callback(it, xn, J[0] + lam * J[1])
        # constant momentum, restarted (β = 0) when J (at this iteration's λ_k) rises or the momentum points uphill
        beta = 0.0 if J[0] + lam_k * J[1] > J_prev[0] + lam_k * J_prev[1] or ab < 0 else MOMENTUM
        dy = math.sqrt(cc if beta else aa)
        Ay = Axn + beta * (Axn - Ax)
        Ax = Axn
        J_prev = J
        elapsed = time.monotonic() - started
        if iterations is not None:
            iterations(max(it / max_iter, elapsed / time_limit), stopping.stage(it))
        verdict = stopping.verdict(it, elapsed)  # "converged", "time limit", "iterations" or None: go on
        if verdict is not None:
            stop_reason = verdict
            break
        # y_new = x_new + β b in x_new's place (the result is x_new itself: made only when going on)
        move = (b_new[0], beta * b_new[1])
        del b_new
        k.extrapolate_fixed(xn.ravel(), move[0], move[1])
        y = xn  # noqa: F841 (read at the loop's top: ruff does not follow the loop past the del there)
    return Solved(xn, it, stop_reason, float(stopping.change), Ax, L, lam,
                  None if exact_from is None or exact_from > it else exact_from)


def debias_refit(forward: Callable[[np.ndarray], np.ndarray], G: Callable[[np.ndarray], np.ndarray], g: np.ndarray,
            box: list[Solved], started: float, time_limit: float, residual: Callable[[np.ndarray], float],
            poll: Callable[[], None] | None = None) -> Solved:
    """TV shrinks amplitudes: `DEBIAS_ITER` iterations of `run_fista` at λ = 0 on tv's support
    (voxels above `SUPPORT_FRACTION` of tv's maximum; zero elsewhere, positivity kept) refit
    them by least squares, from L on.

    Parameters
    ----------
    forward, G, g
        As `run_fista`'s.
    box : list
        One element, tv's `Solved`, taken out of it (its image's memory is reused: the caller
        keeps no reference).
    started, time_limit, residual, poll
        As `run_fista`'s.

    Returns
    -------
    Solved
        tv's, with the refit's image, A x and L (its iterations, stop reason, rule value and λ).

    Examples
    --------
    >>> import time
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.fista import Solved, debias_refit
    >>> g = np.array([[0.0, 0.0, 1.0, 1.0]])
    >>> shrunk = Solved(np.array([[0.0, 0.0, 0.8, 0.8]]), 12, "converged", 1e-3, np.zeros((1, 4)), 1.1, 0.1)
    >>> s = debias_refit(lambda v: v.copy(), lambda r: r, g, [shrunk], time.monotonic(), 60.0,
    ...                  lambda Ax: float(np.linalg.norm(Ax - g)))
    >>> s.iterations, s.stop_reason, np.round(s.x, 3).tolist()  # the amplitudes back at 1
    (12, 'converged', [[0.0, 0.0, 1.0, 1.0]])
    """
    x, it, stop_reason, change, Ax, L, lam, exact_from = box.pop()
    support = x > SUPPORT_FRACTION * float(x.max())
    start = [x]
    del x
    refit = run_fista(forward, G, g, start, 0.0, L, True, DEBIAS_ITER, 0.0, started, time_limit, None, residual,
                   support=support, poll=poll)
    return Solved(refit.x, it, stop_reason, change, refit.Ax, refit.L, lam, exact_from)


@numba.njit(parallel=True, cache=True)
def axpy(y: np.ndarray, x: np.ndarray, s: float) -> None:
    """In place, y += s x (flat arrays of one dtype).

    Parameters
    ----------
    y : ndarray
        Flat ``(N,)``, float32 or float64; overwritten.
    x : ndarray
        Flat ``(N,)``, y's dtype.
    s : float
        The factor.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.fista import axpy
    >>> y = np.array([1.0, 2.0])
    >>> axpy(y, np.array([1.0, -1.0]), 0.5)
    >>> y.tolist()
    [1.5, 1.5]
    """
    for i in numba.prange(y.size):
        y[i] += s * x[i]


@numba.njit(parallel=True, cache=True)
def moves(xn: np.ndarray, v: np.ndarray, gy: np.ndarray, inv_l: float, b_last: np.ndarray, scale_last: float,
           beta: float) -> tuple[float, float, float, float, float, float]:
    """The sums the solver's momentum, its gain and its stopping rule need, in one pass.

    With y = v + inv_l gy (the gradient step v = y − gy / L undone) and x = y − scale_last b_last
    (y's extrapolation undone: `fpscan.service.recon.tv.stores.store_move`), a = xn − y and b =
    xn − x: (⟨a, b⟩, ‖a‖², ‖a + β b‖², ‖b‖², ‖xn‖², max |b|), summed in float64.

    Parameters
    ----------
    xn, v, gy : ndarray
        Flat ``(N,)`` arrays of one dtype: the new iterate, the gradient step and the gradient.
    inv_l : float
        1 / L.
    b_last : ndarray of int16
        The last move's fixed-point values ``(N,)``.
    scale_last : float
        Their scale.
    beta : float
        The momentum β of the candidate y_new = xn + β b.

    Returns
    -------
    tuple of float
        (⟨a, b⟩, ‖a‖², ‖a + β b‖², ‖b‖², ‖xn‖², max |b|).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.fista import moves
    >>> xn, zero = np.array([1.0, 2.0]), np.zeros(2)
    >>> moves(xn, zero, zero, 1.0, np.zeros(2, dtype=np.int16), 0.0, 0.5)  # from y = x = 0
    (5.0, 5.0, 11.25, 5.0, 5.0, 2.0)
    """
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


#: the CPU's kernel set (`fpscan.service.recon.tv.kernels`): the numba kernels here and in
#: `fpscan.service.recon.tv.prox` / `fpscan.service.recon.tv.stores`
COMPILED = Kernels(np.ascontiguousarray, lambda n: np.zeros(n, dtype=np.int16),
                    lambda a, b: np.subtract(a, b, dtype=a.dtype), axpy, moves, store_move, extrapolate_fixed,
                    store_gradient, gain_lower_bound, tv_norm, tv_prox_stored,
                    lambda x, support: np.where(support, x, 0).astype(x.dtype))


def kernels_for(x: np.ndarray) -> Kernels:
    """The kernel set for ``x``'s array type: `COMPILED` for a NumPy array, the array
    expressions on CuPy for a GPU run's (`fpscan.service.recon.tv.kernels.array_kernels`).

    Parameters
    ----------
    x : ndarray
        An array of the run (NumPy or CuPy).

    Returns
    -------
    Kernels
        The set `run_fista` works with.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.tv.fista import COMPILED, kernels_for
    >>> kernels_for(np.zeros(3)) is COMPILED
    True
    >>> kernels_for(np.zeros(3)).tv_norm(np.array([[0.0, 1.0]]))
    1.0
    """
    return COMPILED if isinstance(x, np.ndarray) else array_kernels(array_module(x))
