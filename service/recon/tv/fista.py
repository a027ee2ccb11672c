"""tv's solver loop: NER-preconditioned FISTA with a constant momentum and restarts.

Accelerated proximal gradient (FISTA, Beck & Teboulle 2009) on J(p) = ½‖A p − g‖² + λ TV(p),
p >= 0, preconditioned by NER: each iteration takes one forward A (of the new iterate; A y
follows by linearity) and one B = P Aᵀ of the residual (`fpscan.service.recon.tv.preconditioner`),
steps along B(A y − g) with step 1 / L, and applies the proximal map of λ_k TV + positivity
(`fpscan.service.recon.tv.prox`). L starts at `MARGIN` ‖BA‖ (`fpscan.service.recon.tv.geometry`) and is
raised to `MARGIN` × the gain of BA along the last move of the iterates whenever that
exceeds it (free: those products are computed anyway). Momentum: a constant β =
`_MOMENTUM` (y_{k+1} = x_{k+1} + β (x_{k+1} − x_k)), set to 0 for one step (a restart) when J
rises or the momentum points uphill (O'Donoghue & Candès 2015): Nesterov's constant scheme
for a strongly convex objective, with the restarts standing in for the unknown condition
number. J(x) is exact and free (A x is computed anyway). The stopping rule:
`fpscan.service.recon.tv.stopping`; λ and its continuation: `fpscan.service.recon.tv.lam`; what waits
between iterations in 16 bits: `fpscan.service.recon.tv.stores`. `debias_refit` refits the amplitudes
at λ = 0 on tv's support. The measurements behind these choices: docs/tv-measurements.md,
"Solver" and "Memory".

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

from fpscan.service.progress import span
from fpscan.service.recon.tv.kernels import Kernels, array_kernels, array_module
from fpscan.service.recon.tv.lam import Continuation
from fpscan.service.recon.tv.progress import Reporter
from fpscan.service.recon.tv.prox import tv_norm, tv_prox_stored
from fpscan.service.recon.tv.stopping import StoppingRule
from fpscan.service.recon.tv.stores import extrapolate_fixed, gain_lower_bound, store_gradient, store_move

__all__: list[str] = []

MARGIN = 1.1  # step 1 / (MARGIN ‖BA‖)
_MOMENTUM = 0.94  # the momentum β between restarts (constant: module doc)
_DEBIAS_ITER = 10  # iterations of the least-squares refit on the support (debias)
_SUPPORT_FRACTION = 0.05  # the support for debias: p0 above this share of its maximum


class Solved(NamedTuple):
    """What `run_fista` returns: the image ``x``, the ``iterations`` run, the ``stop_reason``
    ("converged", "iterations", "time limit"), the stopping rule's last value ``change``
    (NaN before its window filled), ``Ax`` = A x, the step's ``L`` and the ``lam`` used."""

    x: np.ndarray
    iterations: int
    stop_reason: str
    change: float
    Ax: np.ndarray
    L: float
    lam: float


def run_fista(forward: Callable[[np.ndarray], np.ndarray], G: Callable[[np.ndarray], np.ndarray], g: np.ndarray,
           start: list[np.ndarray], lam: float | Callable[[float], float], L: float, positivity: bool,
           max_iter: int, tol: float, started: float, time_limit: float, report: Reporter | None,
           residual: Callable[[np.ndarray], float], support: np.ndarray | None = None,
           poll: Callable[[], None] | None = None, continuation: Continuation | None = None,
           kernels: Kernels | None = None) -> Solved:
    """Accelerated proximal gradient (FISTA, Beck & Teboulle 2009) on J(p) = ½‖A p − g‖² +
    λ TV(p) (p >= 0 with ``positivity``; p = 0 off ``support`` when given), preconditioned:
    the step is G(A y − g) / L with G = B = P Aᵀ of a residual (module doc); the proximal
    map `fpscan.service.recon.tv.prox.tv_prox`.

    One forward A (of the new iterate; A y follows by linearity) and one G per iteration.
    ``residual(Ax)`` = ‖A x − g‖, so J(x_k) is exact and free; ``poll`` as `tv_prox`. Momentum:
    the constant `_MOMENTUM` (module doc), 0 for one step (a restart, O'Donoghue & Candès 2015)
    when J rises or the momentum points uphill. Stopping rule (`fpscan.service.recon.tv.stopping`): the
    iterate's relative change ‖x_k − x_{k−1}‖ / ‖x_k‖ below ``tol`` in each of the last 3
    iterations ("converged"); else ``max_iter`` iterations ("iterations") or the time limit
    ("time limit"). L rises to `MARGIN` × the gain of BA along the last move of y (free: a
    lower bound of ‖BA‖) when that exceeds it. ``lam`` is λ, or a rule λ(‖A x₀ − g‖) of the
    start's residual (the automatic λ: free, A x₀ is the first forward). With ``continuation``
    the proximal step and the restart test take λ_k = λ · ``continuation.factor(k)``, started
    from the same residual, and the stopping rule waits for λ itself
    (`fpscan.service.recon.tv.lam.Continuation`). ``kernels``: the whole-image kernel set
    (`fpscan.service.recon.tv.kernels`; default the one for the start's array type). Returns `Solved`
    (x, iterations, stop reason, the rule's last value, A x, L, λ). ``forward(v)`` = A v in the
    data's shape; ``start`` is a list holding the first x, which is taken out of it (its
    memory is reused: the caller keeps no reference).

    Memory (the proximal map's dual is d = 2 or 3 images, kept between calls at half the
    working precision's bytes, `store_dual`: |dual| <= 1, so a float32 warm start keeps
    1.5e-5; the last G(A y − g), which only the next iteration's gain reads, and the last
    move b = x − x_prev wait as 16-bit fixed point, `store_gradient` and `store_move`:
    half a float32 image each; x itself is y − β q round(b / q), read back where it is
    needed): while A works, 1 image (the new iterate, which becomes y in its own place), d/2
    and the two halves; while G works, the same with y; while the proximal map works, 2 (the
    gradient step made in y's place, G(A y − g)), the move's half and d + d/2 at most (its
    dual at full precision beside the stored one), then one more for the new iterate, made
    from the stored dual once the full one is freed (`tv_prox_stored`). At the paper's size
    (d = 3) that is 7 images in the proximal map and 3 beside the operator's k-space (about 3
    images there). Everything that needs y or x after y's gradient step (the restart test,
    ‖y_new − y‖ for the gain for both momenta y_new can take, the new move) is summed before
    A works, with y = the step + G(A y − g) / L (`moves`), so y's memory is free
    then. The vectors are C-contiguous: the in-place kernels see them through flat views."""
    k = kernels or kernels_for(start[0])  # the compiled loops for NumPy arrays, CuPy's for a GPU run
    x = k.contiguous(start.pop())
    if support is not None:
        x = k.masked(x, support)
    iterations = span(report, 0.1, 1.0)
    Ax = forward(x)
    r0 = residual(Ax)
    if callable(lam):  # λ from the start's residual ‖A x − g‖ (the automatic λ's rule)
        lam = float(lam(r0))
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
    stopping = StoppingRule(tol, max_iter, time_limit, continuation.iterations if continuation is not None else 0)
    stored = None  # the proximal map's dual between calls, in half the bytes (`store_dual`)
    it, stop_reason = 0, "iterations"
    xn = y  # for max_iter = 0, which the callers never ask
    for it in range(1, max_iter + 1):
        lam_k = lam * continuation.factor(it) if continuation is not None else lam
        Gy = G(k.subtract(Ay, g))  # the residual in the working dtype (B's input)
        if G_prev is not None and dy > 0:  # the gain of BA along the last move of y: a lower bound of ‖BA‖
            gain = k.gain_lower_bound(Gy.ravel(), G_prev) / dy
            if MARGIN * gain > L:  # the step was too long for what the iterates excite
                L = MARGIN * gain
        G_prev = None
        v = y  # the gradient step y − G(A y − g) / L, in y's place (y = v + Gy / L from here on)
        del y, xn
        k.axpy(v.ravel(), Gy.ravel(), -1.0 / L)
        box: list[np.ndarray | None] = [stored]  # handed over: freed inside once restored
        stored = None
        xn, stored = k.tv_prox_stored(v, lam_k / L, positivity, support, box, poll)  # None at λ = 0 (no dual)
        # a = x_new − y, b = x_new − x: the restart test ⟨a, b⟩ < 0 and ‖y_new − y‖ = ‖a + β b‖
        # for β = 0 and `_MOMENTUM`, now, so that y (v) is free while A works; b kept as int16
        ab, aa, cc, bb, nn, b_max = k.moves(xn.ravel(), v.ravel(), Gy.ravel(), 1.0 / L, move[0], move[1], _MOMENTUM)
        b_new = k.store_move(xn.ravel(), v.ravel(), Gy.ravel(), 1.0 / L, move[0], move[1], b_max)
        del v, move
        G_prev = k.store_gradient(Gy)  # for the next gain, in half (float64: a quarter) of the bytes
        del Gy
        Axn = forward(xn)
        J = parts(Axn, xn)
        # constant momentum, restarted (β = 0) when J (at this iteration's λ_k) rises or the momentum points uphill
        beta = 0.0 if J[0] + lam_k * J[1] > J_prev[0] + lam_k * J_prev[1] or ab < 0 else _MOMENTUM
        dy = math.sqrt(cc if beta else aa)
        Ay = Axn + beta * (Axn - Ax)
        Ax = Axn
        J_prev = J
        stopping.observe(bb, nn)
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
    return Solved(xn, it, stop_reason, float(stopping.change), Ax, L, lam)


def debias_refit(forward: Callable[[np.ndarray], np.ndarray], G: Callable[[np.ndarray], np.ndarray], g: np.ndarray,
            box: list[Solved], started: float, time_limit: float, residual: Callable[[np.ndarray], float],
            poll: Callable[[], None] | None = None) -> Solved:
    """TV shrinks amplitudes: `_DEBIAS_ITER` iterations of `run_fista` at λ = 0 on tv's support
    (voxels above `_SUPPORT_FRACTION` of tv's maximum; zero elsewhere, positivity kept) refit
    them by least squares, from L on. ``box`` is a list holding tv's `Solved`, taken out of it
    (its image's memory is reused: the caller keeps no reference); the other arguments are
    `run_fista`'s. Returns tv's `Solved` with the refit's image, A x and L."""
    x, it, stop_reason, change, Ax, L, lam = box.pop()
    support = x > _SUPPORT_FRACTION * float(x.max())
    start = [x]
    del x
    refit = run_fista(forward, G, g, start, 0.0, L, True, _DEBIAS_ITER, 0.0, started, time_limit, None, residual,
                   support=support, poll=poll)
    return Solved(refit.x, it, stop_reason, change, refit.Ax, refit.L, lam)


@numba.njit(parallel=True, cache=True)
def difference_norm(a: np.ndarray, b: np.ndarray) -> float:
    """‖a − b‖₂ of two flat arrays, summed in float64 (no work array)."""
    total = 0.0
    for i in numba.prange(a.size):
        d = np.float64(a[i]) - np.float64(b[i])
        total += d * d
    return math.sqrt(total)


@numba.njit(parallel=True, cache=True)
def axpy(y: np.ndarray, x: np.ndarray, s: float) -> None:
    """In place, y += s x (flat arrays of one dtype)."""
    for i in numba.prange(y.size):
        y[i] += s * x[i]


@numba.njit(parallel=True, cache=True)
def moves(xn: np.ndarray, v: np.ndarray, gy: np.ndarray, inv_l: float, b_last: np.ndarray, scale_last: float,
           beta: float) -> tuple[float, float, float, float, float, float]:
    """With y = v + inv_l gy (the gradient step v = y − gy / L undone) and x = y − scale_last
    b_last (y's extrapolation undone: `store_move`), a = xn − y and b = xn − x (flat
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


#: the CPU's kernel set (`fpscan.service.recon.tv.kernels`): the numba kernels here and in
#: `fpscan.service.recon.tv.prox` / `fpscan.service.recon.tv.stores`
COMPILED = Kernels(np.ascontiguousarray, lambda n: np.zeros(n, dtype=np.int16),
                    lambda a, b: np.subtract(a, b, dtype=a.dtype), axpy, moves, store_move, extrapolate_fixed,
                    store_gradient, gain_lower_bound, tv_norm, tv_prox_stored,
                    lambda x, support: np.where(support, x, 0).astype(x.dtype))


def kernels_for(x: np.ndarray) -> Kernels:
    """The kernel set for ``x``'s array type: the compiled one for a NumPy array, the array
    expressions on CuPy for a GPU run's (`fpscan.service.recon.tv.kernels.array_kernels`)."""
    return COMPILED if isinstance(x, np.ndarray) else array_kernels(array_module(x))
