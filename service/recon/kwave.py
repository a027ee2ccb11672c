"""Drop-in equivalents of k-Wave's `kspaceLineRecon` (2-D) and `kspacePlaneRecon` (3-D).

Transcribed from the algorithm as documented in `shared/reference/KWAVE_RECON_NOTES.md`
(k-Wave commit 0f1a70f, files last updated 8 June 2017): mirror the data in time to
2 N_t - 1 samples, FFT, multiply by sf = c² sqrt((ω/c)² - k_lat²) / (2ω) (c/2 at DC),
zero the evanescent part |ω| < c |k_lat|, interpolate along ω onto ω' = c |k| (k the grid
with the mirrored length in depth), zero out-of-range queries, inverse FFT, keep the
positive-depth half and scale by 4/c; optional positivity. Interpolation as Octave 7.3
does it: '*linear'/'linear', '*nearest'/'nearest' (ties go to the upper node) and
'cubic'/'*cubic' = pchip along ω (Fritsch-Carlson slopes).

Output grid: (N_t, N_y) / (N_t, N_y, N_z), row i at depth i c dt (row 0 = the sensor
plane), columns at the sensor positions.

The numbers are k-Wave's, computed on the symmetries k-Wave leaves unused (real data:
lateral rfft; the mirrored series is even: one half of the ω and k_z axes, each column's
mapping in one compiled loop), which makes it a few times faster and its peak memory a
few times the input instead of ~15 times. The data stay time first, as the lateral FFT
leaves them (no transpose), and the time and depth transforms of the even series are one
real matrix product each up to `MATRIX_MAX_N` samples (BLAS beats the FFT at k-Wave's
odd lengths there); above it, two smaller products by the prime-factor algorithm where
2 N_t - 1 splits into coprime factors (`_EvenPFA`: 2047 = 23·89 at k-Wave's 1024 samples),
else FFTs of the mirrored series. The lateral real DFT runs as a matrix product at lengths
with a large prime factor (`product_length`: 226 = 2·113, the paper's scan), an FFT otherwise.
"""
from __future__ import annotations

import contextlib
import functools
import math
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Protocol

import numba
import numpy as np
import numpy.typing as npt
import scipy.fft

from driver.physics import fft_engine
from driver.physics.fast_lengths import largest_prime_factor
from driver.physics.lateral import irfft_lateral
from driver.physics.nufft import group_columns
from service.progress import Fraction, rising, span
from service.recon import checks

if TYPE_CHECKING:
    from concurrent.futures import Executor

    from threadpoolctl import ThreadpoolController

__all__ = ["transform_lengths", "product_length", "PRODUCT_MAX_N", "kspace_line_recon", "kspace_plane_recon"]

_INTERPS = {"linear": "linear", "*linear": "linear", "nearest": "nearest", "*nearest": "nearest",
            "cubic": "cubic", "*cubic": "cubic"}


def _kvec(n: int, d: float) -> np.ndarray:
    """kWaveGrid.makeDim: (2 pi / d) * n with the middle element forced to 0."""
    if n % 2 == 0:
        v = np.arange(-n // 2, n // 2) / n
    else:
        v = np.arange(-(n - 1) // 2, (n - 1) // 2 + 1) / n
    v[n // 2] = 0.0
    return (2 * np.pi / d) * v


def _pchip_columns(P: np.ndarray, w: np.ndarray, w_new_cols: np.ndarray) -> np.ndarray:
    """Piecewise-cubic Hermite (pchip, Octave's 'cubic') interpolation along axis 0 of P
    (n_w, n_cols) from the uniform nodes w to a query vector per column (w_new_cols,
    (n_q, n_cols)); queries above max(w) -> 0 (MATLAB's NaN / Octave's NA, zeroed by
    k-Wave). Columns sharing k_lat² share their query vector and are interpolated together.
    (Nearest and linear run in the compiled `_map_columns`.) scipy.interpolate is imported
    here, by the one mode that uses it: its import (~0.2 s) is most of the k-Wave modes' own."""
    import scipy.interpolate

    wmax = w[-1]
    out = np.zeros((w_new_cols.shape[0], P.shape[1]), dtype=np.complex128)
    gvals, gptr, order = group_columns(w_new_cols[0, :])
    for g in range(len(gvals)):
        cols = order[gptr[g] : gptr[g + 1]]
        q = w_new_cols[:, cols[0]]
        vals = P[:, cols]
        re = scipy.interpolate.PchipInterpolator(w, vals.real, axis=0, extrapolate=False)(q)
        im = scipy.interpolate.PchipInterpolator(w, vals.imag, axis=0, extrapolate=False)(q)
        res = np.where((q > wmax)[:, None], 0.0, re + 1j * im)
        out[:, cols] = np.nan_to_num(res)
    return out


# k-Wave's mirrored series is even, so its DFT of odd length M = 2 N - 1 (k-Wave's; 511 =
# 7·73, 2047 = 23·89: often a large prime factor) is the real-even transform
# y_k = a_0 + 2 Σ_{n=1}^{N-1} a_n cos(2π k n / M), k = 0..N-1 (`_even_matrix`). Up to this N
# it runs as a real matrix product (BLAS) per chunk of columns, above it as the FFT of the
# mirrored series. Per output point, 2 cores, float64
# (docs/performance.md): the product 7 ns at N = 128, 13 ns at 256, 19 ns at 384, 24 ns at
# 512; the FFT 20-35 ns at any N.
MATRIX_MAX_N = 400


def _even_matrix(n: int) -> np.ndarray:
    """(n, n) float64 matrix of the real-even DFT of odd length M = 2 n - 1, first half kept:
    ``C[k, j] = w_j cos(2π k j / M)``, w_0 = 1, w_j = 2 (the argument reduced exactly: k j
    mod M in integers). ``C @ a`` along time (forward), or ``C @ a / M`` along depth
    (inverse), is what k-Wave's mirror to M samples, (i)fft and (i)fftshift amount to for
    the non-negative half."""
    m = 2 * n - 1
    k = np.arange(n, dtype=np.int64)
    C = np.cos((2 * np.pi / m) * (np.outer(k, k) % m))
    C[:, 1:] *= 2.0
    return C


#: the largest m1 + m2 of a coprime split M = m1 m2 that `_EvenPFA` takes (its flops per
#: point grow with m1 + m2): 2047 = 23·89 (k-Wave's 1024 samples) 112, 3519 = 23·153 176
PFA_MAX_SUM = 200


def _coprime_split(m: int) -> tuple[int, int] | None:
    """The split m = m1 m2 with gcd(m1, m2) = 1, 3 <= m1 <= m2, of least m1 + m2; None if m
    has none (a prime, or a prime power)."""
    best = None
    for m1 in range(3, math.isqrt(m) + 1):
        if m % m1 == 0 and math.gcd(m1, m // m1) == 1 and (best is None or m1 + m // m1 < sum(best)):
            best = (m1, m // m1)
    return best


class _EvenPFA:
    """The real-even transform of `_even_matrix` (times ``scale``) by the prime-factor
    (Good–Thomas) algorithm on a coprime split M = 2 N - 1 = m1 m2 (`_coprime_split`):
    the mirrored series indexed n = (n1 m2 + n2 m1) mod M is a 2-D array (m1, m2) whose 2-D
    DFT, without twiddles, holds y_k at (k mod m1, k mod m2). Both stages are real matrix
    products (BLAS), and both use the evenness of the series: x[-n1, -n2] = x[n1, n2], so
    the DFT along n2 (real input: k2 <= (m2 - 1) / 2) is needed for n1 <= (m1 - 1) / 2 only
    (the other rows are its conjugates), and the result is real and even, so the second
    stage sums 2 Re(...) over those rows and yields every y_k with k2 <= (m2 - 1) / 2 (the
    others at (-k1, -k2)). About M (m1 + m2) flops per real column against the plain
    product's 2 N²: at k-Wave's 1024 samples (2047 = 23·89), 2 cores, float64, 15 ns a
    complex point against the mirrored FFT's 32 ns (docs/performance.md).

    ``pfa(X, out)`` writes the transform of ``X`` (N, cols) real, along axis 0, into ``out``
    (N, cols)."""

    def __init__(self, n: int, split: tuple[int, int], dtype: npt.DTypeLike, scale: float = 1.0) -> None:
        m = 2 * n - 1
        m1, m2 = split
        self.h1, self.h2, self.m1, self.m2 = (m1 - 1) // 2, (m2 - 1) // 2, m1, m2
        n1, n2 = np.arange(self.h1 + 1), np.arange(m2)
        idx = (n2[:, None] * m1 + n1[None, :] * m2) % m  # (m2, h1 + 1): rows n2, columns n1
        self.gather = np.minimum(idx, m - idx).ravel()  # the mirrored series' sample n is a_|n|
        ang2 = (2 * np.pi / m2) * (np.outer(np.arange(self.h2 + 1), n2) % m2)  # (h2 + 1, m2)
        # stage 1: Y[k2, n1] = Yc - i Ys, rows (k2, cos) and (k2, sin) interleaved
        self.stage1 = np.stack([np.cos(ang2), np.sin(ang2)], axis=1).reshape(-1, m2).astype(dtype)
        ang1 = (2 * np.pi / m1) * (np.outer(np.arange(m1), n1) % m1)  # (m1, h1 + 1)
        w = np.full(self.h1 + 1, 2.0 * scale)
        w[0] = scale  # row n1 = 0 is its own mirror
        self.stage2 = np.concatenate([np.cos(ang1) * w, -np.sin(ang1) * w], axis=1).astype(dtype)
        k = np.arange(n)
        k1, k2 = k % m1, k % m2
        flip = k2 > self.h2  # y_k = X[-k1, -k2]
        self.scatter = np.where(flip, m2 - k2, k2) * m1 + np.where(flip, (-k1) % m1, k1)
        self._local = threading.local()  # each thread's work arrays (`_work`)

    def __call__(self, X: np.ndarray, out: np.ndarray) -> None:
        c = X.shape[1]
        G, Y, Z = self._work(c, X.dtype)
        np.take(X, self.gather, axis=0, out=G, mode="clip")  # (m2 (h1 + 1), c)
        np.matmul(self.stage1, G.reshape(self.m2, -1), out=Y.reshape(self.stage1.shape[0], -1))  # views
        np.matmul(self.stage2, Y, out=Z)  # (h2 + 1, m1, c): X[k2, k1]
        np.take(Z.reshape(-1, c), self.scatter, axis=0, out=out, mode="clip")

    def _work(self, c: int, dtype: np.dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The calling thread's work arrays for ``c`` columns (C-contiguous views of buffers made once
        and reused: a fresh set per chunk cost the system's page faults each time the
        allocator had returned them, 2.6 -> 3.3 s of k-Wave's algorithm at 1024 × 226² in a
        fresh process)."""
        sizes = (len(self.gather) * c, self.stage1.shape[0] * (self.h1 + 1) * c, (self.h2 + 1) * self.m1 * c)
        work = getattr(self._local, "work", None)
        if work is None or work[0].size < sizes[0] or work[0].dtype != dtype:
            work = tuple(np.empty(n, dtype) for n in sizes)
            self._local.work = work
        G, Y, Z = (w[:n] for w, n in zip(work, sizes))
        return (G.reshape(len(self.gather), c), Y.reshape(self.h2 + 1, 2 * (self.h1 + 1), c),
                Z.reshape(self.h2 + 1, self.m1, c))


def _mirrored_fft(a: np.ndarray) -> np.ndarray:
    """The real-even transform of `_even_matrix` along axis 0 of ``a`` (N, cols)
    complex, as the FFT of the mirrored series of length 2 N - 1 (its even half is exact to
    rounding): (N, cols), C-contiguous."""
    n = a.shape[0]
    buf = np.empty((2 * n - 1,) + a.shape[1:], dtype=a.dtype)
    buf[:n] = a
    buf[n:] = a[n - 1 : 0 : -1]
    return scipy.fft.fft(buf, axis=0, overwrite_x=True, workers=-1)[:n]


_BLAS_LOCK = threading.Lock()  # one product section at a time per process (see below)


@functools.cache
def _blas() -> ThreadpoolController:
    """The controller (threadpoolctl) of the loaded BLAS libraries, made on first use."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController().select(user_api="blas")


class _MatMul(Protocol):
    """``matmul(C, X, out)`` of `_products_in_threads`: ``out = C @ X``."""

    def __call__(self, C: np.ndarray | _EvenPFA, X: np.ndarray, out: np.ndarray) -> None: ...


class _MatMulRows(Protocol):
    """``matmul_rows(C, X, out, over=False)`` of `_products_in_threads`: ``out = X @ C``."""

    def __call__(self, C: np.ndarray, X: np.ndarray, out: np.ndarray, over: bool = False) -> None: ...


#: the k-space mapping of `_recon`: ``mapping(P, c0, c1, out)`` for the columns c0:c1
_Mapping = Callable[[np.ndarray, int, int, np.ndarray], None]


@contextlib.contextmanager
def _products_in_threads() -> Iterator[tuple[_MatMul, _MatMulRows]]:
    """A context giving ``(matmul, matmul_rows)``: ``matmul(C, X, out)`` writes ``out = C @ X``
    (or ``C(X, out)`` for an `_EvenPFA`) with the columns of ``X`` split over as many threads
    as BLAS had, each running single-threaded BLAS; ``matmul_rows(C, X, out)`` writes
    ``out = X @ C`` with the rows of ``X`` split (both C-contiguous). With ``over=True``,
    ``out`` is written over ``X``'s own memory: it starts where ``X`` starts and its rows are
    no longer than ``X``'s (`_rows_over`).

    OpenBLAS's own threads spin for about 0.1 s after a product before they sleep; the
    compiled kernels and FFTs that follow it here then ran at half speed (the mapping 17 ->
    34 ms at 256 x 128²). Threads of our own, with BLAS at one thread in them
    (threadpoolctl), wait for the next product without spinning. BLAS's thread count is
    process-wide, so product sections take a lock: two at once in one process would restore
    each other's limit."""
    from concurrent.futures import ThreadPoolExecutor

    with _BLAS_LOCK:
        blas = _blas()
        parts = max((lib["num_threads"] for lib in blas.info()), default=1)
        with blas.limit(limits=1), ThreadPoolExecutor(parts) as pool:

            def matmul(C: np.ndarray | _EvenPFA, X: np.ndarray, out: np.ndarray) -> None:
                apply = C if isinstance(C, _EvenPFA) else functools.partial(np.matmul, C)
                cuts = [X.shape[1] * i // parts for i in range(parts + 1)]
                done = [pool.submit(apply, X[:, c0:c1], out=out[:, c0:c1])
                        for c0, c1 in zip(cuts, cuts[1:]) if c1 > c0]
                for d in done:
                    d.result()

            def matmul_rows(C: np.ndarray, X: np.ndarray, out: np.ndarray, over: bool = False) -> None:
                cuts = [X.shape[0] * i // parts for i in range(parts + 1)]
                if over:
                    _rows_over(pool, C, X, out, cuts)
                    return
                done = [pool.submit(np.matmul, X[r0:r1], C, out=out[r0:r1])
                        for r0, r1 in zip(cuts, cuts[1:]) if r1 > r0]
                for d in done:
                    d.result()

            yield matmul, matmul_rows


_OVER_BYTES = 512 << 10  # rows of X a thread of `_rows_over` takes at a time (L2-resident)


def _rows_over(pool: Executor, C: np.ndarray, X: np.ndarray, out: np.ndarray, cuts: list[int]) -> None:
    """``out = X @ C`` written over ``X``'s own memory (``out`` (R, m) starts where ``X`` (R, k)
    does, m <= k, both C-contiguous), the rows split at ``cuts`` over the threads of ``pool``.

    Output row r lies below input row r (r m <= r k), so a thread that goes through its rows
    in order, a block at a time (each block's product into its own small array, then copied
    into place), writes only over rows it has read. Only its first rows reach below its
    first input row, into the previous thread's: their products are kept aside and copied
    into place once every thread is done."""
    m, k = out.shape[1], X.shape[1]
    step = max(1, _OVER_BYTES // (k * X.itemsize))

    def part(r0: int, r1: int) -> np.ndarray:
        head = min(r1, -(-r0 * k // m))  # rows r < head write below input row r0
        kept = np.matmul(X[r0:head], C)
        tmp = np.empty((step, m), dtype=out.dtype)
        for a in range(head, r1, step):
            b = min(a + step, r1)
            np.matmul(X[a:b], C, out=tmp[: b - a])
            out[a:b] = tmp[: b - a]
        return kept

    done = [(r0, pool.submit(part, r0, r1)) for r0, r1 in zip(cuts, cuts[1:]) if r1 > r0]
    kept = [(r0, d.result()) for r0, d in done]  # every thread has read all its rows
    for r0, rows in kept:
        out[r0 : r0 + rows.shape[0]] = rows


#: the longest lateral length `product_length` gives to a matrix product
PRODUCT_MAX_N = 1024


def product_length(n: int) -> bool:
    """Whether the lateral real DFT of length ``n`` (k-Wave's unpadded lateral grid: the scan's
    own size) runs as a matrix product instead of an FFT: ``n`` <= `PRODUCT_MAX_N` with a prime
    factor p >= 31 and n <= 4 p. pocketfft takes such a length by a generic pass of p or by
    Bluestein's chirp-z, at about twice the cost per point of a 5-smooth one; a real product
    (BLAS) costs 2 (n + 2) flops a point whatever n's factors. Per point, 2 cores
    (docs/performance.md), float64, FFT / product: n = 97 11.0 / 4.5 ns, 226 = 2·113 8.7 / 6.0,
    302 = 2·151 10.8 / 7.7, 454 = 2·227 15.3 / 10.9; but 518 = 14·37 3.8 / 12.3; float32
    about half of each.

    Parameters
    ----------
    n : int
        The lateral length (samples along the scan's last lateral axis).

    Returns
    -------
    bool
        True where `kspace_line_recon` / `kspace_plane_recon` take that axis's real DFT and its
        inverse as matrix products (for arrays above `driver.physics.fft_engine.SMALL_ELEMENTS`).

    Examples
    --------
    >>> from service.recon.kwave import product_length
    >>> product_length(226), product_length(240), product_length(518)
    (True, False, False)
    """
    n = int(n)
    if n > PRODUCT_MAX_N or n < 31:
        return False
    p = largest_prime_factor(n)
    return p >= 31 and n <= 4 * p


@functools.lru_cache(maxsize=8)
def _lateral_matrices(n: int, dtype: np.dtype) -> tuple[np.ndarray, np.ndarray]:
    """The real DFT of length ``n`` and its inverse as real matrices in ``dtype``: W (n, 2 h),
    h = n // 2 + 1, with x @ W the interleaved (real, imaginary) pairs of ``rfft(x)``; and
    V (2 h, n) with (interleaved X) @ V = ``irfft(X, n)`` (the imaginary parts of the
    zero and Nyquist frequencies ignored, as irfft does: their sines vanish). The
    arguments are reduced exactly (j k mod n in integers)."""
    h = n // 2 + 1
    ang = (2 * np.pi / n) * (np.outer(np.arange(n), np.arange(h)) % n)  # (n, h)
    cos, sin = np.cos(ang), np.sin(ang)
    W = np.stack([cos, -sin], axis=2).reshape(n, 2 * h)
    weight = np.full(h, 2.0 / n)
    weight[0] = 1.0 / n
    if n % 2 == 0:
        weight[-1] = 1.0 / n
    V = np.stack([weight[:, None] * cos.T, -weight[:, None] * sin.T], axis=1).reshape(2 * h, n)
    return W.astype(dtype), V.astype(dtype)


def _lateral_forward(p: np.ndarray, lat_axes: tuple[int, ...]) -> np.ndarray:
    """``scipy.fft.rfftn(p, axes=lat_axes)`` (p time first, real), the real axis (the last)
    as a matrix product where `product_length` says so (a large array only)."""
    n = p.shape[-1]
    if fft_engine.is_small(p.size):
        return scipy.fft.rfftn(p, axes=lat_axes, workers=-1)
    if not product_length(n):  # rfftn's second pass would take an array of its own: in place here
        out = scipy.fft.rfft(p, axis=-1, workers=-1)
        if len(lat_axes) == 2:
            out = scipy.fft.fft(out, axis=lat_axes[0], overwrite_x=True, workers=-1)
        return out
    W, _ = _lateral_matrices(n, p.dtype)
    rows = np.ascontiguousarray(p).reshape(-1, n)
    cdtype = np.complex64 if p.dtype == np.float32 else np.complex128
    out = np.empty(p.shape[:-1] + (n // 2 + 1,), dtype=cdtype)
    with _products_in_threads() as (_, matmul_rows):
        matmul_rows(W, rows, out.reshape(rows.shape[0], -1).view(p.dtype))
    if len(lat_axes) == 2:
        out = scipy.fft.fft(out, axis=lat_axes[0], overwrite_x=True, workers=-1)
    return out


def _lateral_inverse(A: np.ndarray, lat_shape: tuple[int, ...], lat_axes: tuple[int, ...]) -> np.ndarray:
    """`driver.physics.lateral.irfft_lateral` (``A`` consumed), the real axis as a matrix
    product where `product_length` says so (a large array only); the image is written over
    ``A``'s own memory (a view of it is returned)."""
    n = lat_shape[-1]
    rdtype = np.float32 if A.dtype == np.complex64 else np.float64
    if fft_engine.is_small(A.size // A.shape[-1] * n) or not product_length(n):  # the output's size
        over: np.ndarray | None = None
        if A.flags.c_contiguous and lat_axes[0] == 1:  # slab by slab over the spectrum (irfft_lateral's out)
            over = A.reshape(-1).view(rdtype)[: A.size // A.shape[-1] * n].reshape(A.shape[:-1] + (n,))
        return irfft_lateral(A, lat_shape, lat_axes, out=over)
    if len(lat_axes) == 2:
        A = scipy.fft.ifft(A, axis=lat_axes[0], overwrite_x=True, workers=-1)
    _, V = _lateral_matrices(n, np.dtype(rdtype))
    rows = np.ascontiguousarray(A).reshape(-1, A.shape[-1]).view(rdtype)
    out = rows.reshape(-1)[: rows.shape[0] * n].reshape(rows.shape[0], n)  # over the spectrum
    with _products_in_threads() as (_, matmul_rows):
        matmul_rows(V, rows, out, over=True)
    return out.reshape(A.shape[:-1] + (n,))


_BLOCK = 8  # columns the mapping takes at a time (8 complex128: two cache lines of a row)


@numba.njit(parallel=True, cache=True)
def _map_columns(P: np.ndarray, lat2: np.ndarray, w: np.ndarray, kz: np.ndarray, c: float, nearest: bool,
                 out: np.ndarray) -> None:
    """k-Wave's k-space mapping for the ω >= 0 half, one lateral column per column of P
    (n_w, n_cols), time first (compiled, in place of numpy fancy indexing): out[l, j] =
    interp_ω(sf · P[:, j]) evaluated at ω' = c sqrt(kz_l² + lat2_j).

    sf = c² sqrt((ω/c)² - k_lat²) / (2ω) (c/2 at ω = k_lat = 0), zero where |ω| < c|k_lat|;
    linear interpolation or the nearest node (ties to the upper node) on the uniform nodes
    w, located as searchsorted(w, ω', side='right') - 1 clipped to [0, n_w - 2] (k-Wave's
    interp1 on the same nodes); queries above w[-1] give 0."""
    n_w, n_cols = P.shape
    n_q = kz.shape[0]
    wmax = w[n_w - 1]
    dw = w[1] - w[0]
    n_blocks = (n_cols + _BLOCK - 1) // _BLOCK
    for b in numba.prange(n_blocks):  # a block of adjacent columns: whole cache lines a row
        j0 = b * _BLOCK
        nb = min(_BLOCK, n_cols - j0)
        blk = np.empty((n_w, _BLOCK), dtype=P.dtype)
        for jj in range(nb):
            l2 = lat2[j0 + jj]
            kl = c * math.sqrt(l2)
            for i in range(n_w):
                wi = w[i]
                if wi == 0.0 and l2 == 0.0:
                    sf = c / 2.0
                elif abs(wi) < kl:
                    sf = 0.0
                else:
                    arg = (wi / c) ** 2 - l2
                    sf = c * c * math.sqrt(arg) / (2.0 * wi) if arg >= 0.0 and wi != 0.0 else 0.0
                blk[i, jj] = sf * P[i, j0 + jj]
        for q in range(n_q):
            for jj in range(nb):
                l2 = lat2[j0 + jj]
                wq = c * math.sqrt(kz[q] * kz[q] + l2)
                if wq > wmax:
                    out[q, j0 + jj] = 0.0
                    continue
                i = min(int(wq / dw), n_w - 2)
                while i > 0 and w[i] > wq:
                    i -= 1
                while i < n_w - 2 and w[i + 1] <= wq:
                    i += 1
                if nearest:
                    out[q, j0 + jj] = blk[i + 1, jj] if (wq - w[i]) >= (w[i + 1] - wq) else blk[i, jj]
                else:
                    frac = (wq - w[i]) / (w[i + 1] - w[i])
                    out[q, j0 + jj] = blk[i, jj] * (1.0 - frac) + blk[i + 1, jj] * frac


_CUBIC_BYTES = 2 << 20  # one of `_cubic_block`'s arrays of a chunk of columns (memory.KWAVE_STEP_BYTES)


def _cubic_block(P_half: np.ndarray, w_full: np.ndarray, lat2: np.ndarray, phase: np.ndarray, kx: np.ndarray,
                 c: float) -> np.ndarray:
    """The pchip (Octave 'cubic') mapping of a chunk of columns (rows of ``P_half``, (cols, N)
    -> (cols, N)) on the full mirrored ω grid (pchip slopes at ω = 0 see the negative
    side), as k-Wave evaluates it.

    pchip acts on the real and imaginary parts separately, so it does not commute with a
    complex phase: the columns carry the phase ``phase`` that k-Wave's lateral
    ``ifftshift`` gives them (1 or -1 for even sizes) while being interpolated."""
    n = P_half.shape[1]
    P = np.concatenate([P_half[:, :0:-1], P_half], axis=1).T * phase[None, :]  # even in ω
    wc = w_full[:, None]
    l2 = lat2[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        arg = (wc / c) ** 2 - l2
        sf = np.where(arg >= 0, c**2 * np.sqrt(np.maximum(arg, 0)) / (2 * wc), 0.0)
    sf[(wc == 0) & (l2 == 0)] = c / 2
    block = sf * P
    block[np.abs(wc) < c * np.sqrt(l2)] = 0
    block[~np.isfinite(block)] = 0
    w_new = c * np.sqrt((kx[n - 1 :] ** 2)[:, None] + l2)
    return (_pchip_columns(block, w_full, w_new) * np.conj(phase)[None, :]).T


def transform_lengths(data_shape: Sequence[int]) -> dict[str, tuple[int, ...]]:
    """The DFT lengths `kspace_line_recon` / `kspace_plane_recon` run for data of a given shape.

    These are k-Wave's grids, not rounded to fast lengths: the mirrored length fixes the ω
    and k_z nodes k-Wave interpolates between, and the unpadded lateral grid its lateral
    periodicity, so any other length changes the numbers beyond rounding. An exact DFT of
    these lengths through fast ones (Bluestein's chirp-z: two FFTs at a fast length
    >= 3 N_t - 2) would cost about what pocketfft's own handling costs: 0.75x, 1.06x, 1.08x
    of it at N_t = 256, 1024, 3519 (per-point FFT timings, issue 20). Up to
    `MATRIX_MAX_N` samples the temporal and depth DFTs run as matrix products instead
    (faster than any FFT of these lengths there), above it by the prime-factor algorithm
    where 2 N_t - 1 has a coprime split (`PFA_MAX_SUM`), and the lateral real DFT as a
    product at lengths `product_length` names; the lengths stay the same.

    Parameters
    ----------
    data_shape : tuple of int
        ``(N_t, N_y)`` or ``(N_t, N_y, N_z)``, time first.

    Returns
    -------
    dict of str to tuple of int
        ``"lateral"`` the data's own lateral shape, ``"temporal"`` and ``"depth"``
        ``(2 N_t - 1,)``, the mirrored series.

    Raises
    ------
    ValueError
        A shape that is not 2-D or 3-D with N_t >= 2.

    References
    ----------
    .. [1] B. E. Treeby, B. T. Cox, "k-Wave: MATLAB toolbox for the simulation and
       reconstruction of photoacoustic wave fields", J. Biomed. Opt. 15 (2010);
       ``kspaceLineRecon.m`` / ``kspacePlaneRecon.m`` (``shared/reference/KWAVE_RECON_NOTES.md``).

    Examples
    --------
    >>> from service.recon.kwave import transform_lengths
    >>> transform_lengths((40, 32))
    {'lateral': (32,), 'temporal': (79,), 'depth': (79,)}
    >>> transform_lengths((40,))
    Traceback (most recent call last):
    ...
    ValueError: data_shape must be (N_t, N_y) or (N_t, N_y, N_z) with N_t >= 2, got (40,)
    """
    shape = tuple(int(n) for n in data_shape)
    if len(shape) not in (2, 3) or shape[0] < 2 or min(shape) < 1:
        raise ValueError(f"data_shape must be (N_t, N_y) or (N_t, N_y, N_z) with N_t >= 2, got {data_shape!r}")
    ntm = 2 * shape[0] - 1
    return {"lateral": shape[1:], "temporal": (ntm,), "depth": (ntm,)}


_CHUNK_BYTES = 8 << 20  # the product path's columns per chunk: 8 MiB of spectrum (2048 at N = 256)


def _by_products(a: np.ndarray, mapping: _Mapping, scale: float, rdtype: np.dtype, progress: Fraction | None,
                 split: tuple[int, int] | None = None) -> None:
    """The time -> depth step of `_recon`, in place in ``a`` (N, cols), time first: per
    chunk of columns the real-even transform along time (a product with `_even_matrix`, or
    with a coprime ``split`` of 2 N - 1 the prime-factor algorithm `_EvenPFA`), the
    mapping, the transform along depth (the same, times ``scale``: `_recon` passes the
    inverse's 1 / M times the image's 4 / c, folded into its matrix). Chunks of `_CHUNK_BYTES`: the
    per-chunk spectra stay a small fraction of the volume, and progress is reported (and a
    cancel seen) as each ends."""
    n, n_cols = a.shape
    forward: np.ndarray | _EvenPFA
    inverse: np.ndarray | _EvenPFA
    if split is not None:
        forward, inverse = _EvenPFA(n, split, rdtype), _EvenPFA(n, split, rdtype, scale)
    else:
        C = _even_matrix(n)  # the cosines once: the inverse is the same matrix, scaled
        forward, inverse = C.astype(rdtype, copy=False), (C * scale).astype(rdtype, copy=False)
    chunk = min(n_cols, max(128, _CHUNK_BYTES // (n * a.itemsize)))
    spectra = np.empty((2, n * chunk), dtype=a.dtype)  # P and F of every chunk (no fresh pages per chunk)
    with _products_in_threads() as (matmul, _):
        for c0 in range(0, n_cols, chunk):
            c1 = min(c0 + chunk, n_cols)
            P, F = (buf[: n * (c1 - c0)].reshape(n, c1 - c0) for buf in spectra)
            matmul(forward, a[:, c0:c1].view(rdtype), P.view(rdtype))
            mapping(P, c0, c1, F)
            matmul(inverse, F.view(rdtype), a[:, c0:c1].view(rdtype))
            if progress is not None:
                progress(c1 / n_cols)


def _by_ffts(a: np.ndarray, mapping: _Mapping, scale: float, rdtype: np.dtype, progress: Fraction | None) -> None:
    """The same step as `_by_products` by FFTs of the mirrored series, in ~32 chunks of
    columns (the mirrored series stay a small fraction of the volume); ``scale`` as there."""
    n, n_cols = a.shape
    chunk = max(64, -(-n_cols // 32))
    for c0 in range(0, n_cols, chunk):
        c1 = min(c0 + chunk, n_cols)
        F = np.empty((n, c1 - c0), dtype=a.dtype)
        mapping(_mirrored_fft(a[:, c0:c1]), c0, c1, F)
        np.multiply(_mirrored_fft(F), scale, out=a[:, c0:c1])
        if progress is not None:
            progress(c1 / n_cols)


def _recon(p: np.ndarray, dt: float, c: float, lateral_d: tuple[float, ...], interp: str, pos_cond: bool,
           dtype: npt.DTypeLike = np.float64, progress: Fraction | None = None) -> np.ndarray:
    """k-Wave's algorithm (module doc) on the symmetries it leaves unused: the data are
    real (lateral rfft) and the mirrored series even (one half of the ω and k_z axes), so
    the transforms run on about a quarter of the mirrored volume and the peak memory stays
    a few times the input. Same numbers as k-Wave to rounding."""
    method = _INTERPS.get(interp)
    if method is None:
        raise ValueError(f"Interp must be one of {sorted(_INTERPS)}, got {interp!r}")
    rdtype = checks.check_dtype(dtype)
    nt = p.shape[0]
    if nt < 2:
        raise ValueError("p needs at least 2 time samples")
    ntm = transform_lengths(p.shape)["temporal"][0]
    kx = _kvec(ntm, dt * c)
    w_full = c * kx
    w = w_full[nt - 1 :]  # ω >= 0 nodes
    lat_shape = p.shape[1:]
    lat_axes = tuple(range(1, p.ndim))
    # lateral wavenumbers in rfft order (k-Wave's shifted grid holds the same set)
    kl = [2 * np.pi * scipy.fft.fftfreq(n, d) for n, d in zip(lat_shape[:-1], lateral_d[:-1])]
    kl.append(2 * np.pi * scipy.fft.rfftfreq(lat_shape[-1], lateral_d[-1]))
    lat2 = kl[0][:, None] ** 2 + kl[1][None, :] ** 2 if len(kl) == 2 else kl[0] ** 2
    lat2 = np.ascontiguousarray(np.ravel(lat2), dtype=np.float64)
    if method == "cubic":  # phase of k-Wave's lateral ifftshift: fft(roll(x, -s))_k = e^{2πiks/n} X_k
        ph = [np.exp(2j * np.pi * np.arange(n) * (n // 2) / n) for n in lat_shape[:-1]]
        ph.append(np.exp(2j * np.pi * np.arange(lat_shape[-1] // 2 + 1) * (lat_shape[-1] // 2) / lat_shape[-1]))
        phase = np.ravel(ph[0][:, None] * ph[1][None, :] if len(ph) == 2 else ph[0])
    A = _lateral_forward(np.asarray(p, dtype=rdtype), lat_axes)
    spec_shape = A.shape
    n_cols = int(np.prod(spec_shape[1:]))
    a = A.reshape(nt, n_cols)  # time first: lateral column j is a[:, j]
    kernel = rising(progress)  # strictly increasing fractions, each step through its span
    if kernel is not None:
        kernel(0.15)
    kz = np.ascontiguousarray(kx[nt - 1 :], dtype=np.float64)

    # k-Wave's k-space mapping of columns c0:c1 (P: their ω >= 0 half)
    def mapping(P: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        if method != "cubic":
            _map_columns(P, lat2[c0:c1], w, kz, float(c), method == "nearest", out)
            return
        # pchip's buffers, about ten arrays of (2 N - 1) x step in complex128: `_CUBIC_BYTES` each
        step = max(16, min(-(-n_cols // 32), _CUBIC_BYTES // (ntm * 16)))
        for s0 in range(c0, c1, step):
            s1 = min(s0 + step, c1)
            out[:, s0 - c0 : s1 - c0] = _cubic_block(P[:, s0 - c0 : s1 - c0].T.astype(np.complex128), w_full,
                                                     lat2[s0:s1], phase[s0:s1], kx, c).T

    split = None if nt <= MATRIX_MAX_N else _coprime_split(ntm)
    scale = (4.0 / c) / ntm  # the depth transform's 1 / M and the image's 4 / c, in its matrix or pass
    if nt <= MATRIX_MAX_N or (split is not None and sum(split) <= PFA_MAX_SUM):
        _by_products(a, mapping, scale, rdtype, span(kernel, 0.15, 0.85), split)  # in place: A holds the image's k-space
    else:
        _by_ffts(a, mapping, scale, rdtype, span(kernel, 0.15, 0.85))
    del a
    res = _lateral_inverse(A, lat_shape, lat_axes)
    del A
    if pos_cond:
        np.maximum(res, 0, out=res)
    if kernel is not None:
        kernel(1.0)
    return res.astype(rdtype, copy=False)


def kspace_line_recon(p: npt.ArrayLike, dy: float, dt: float, c: float, data_order: str = "ty",
                      interp: str = "*nearest", pos_cond: bool = False, progress: Fraction | None = None,
                      dtype: npt.DTypeLike = np.float64) -> np.ndarray:
    """2-D planar reconstruction exactly as k-Wave's ``kspaceLineRecon``.

    Parameters
    ----------
    p : ndarray, shape ``(N_t, N_y)`` for ``data_order='ty'`` or ``(N_y, N_t)`` for ``'yt'``
        Pressure, Pa; sample 0 at t = 0.
    dy : float
        Sensor spacing, m.
    dt : float
        Sample interval, s.
    c : float
        Sound speed, m/s.
    data_order : {"ty", "yt"}, optional
        Axis order of ``p``.
    interp : str, optional
        '*nearest' (k-Wave's default), 'nearest', '*linear', 'linear', 'cubic' (Octave: pchip
        along ω).
    pos_cond : bool, optional
        Clip negative values to 0 (k-Wave's PosCond).
    progress : callable, optional
        ``progress(fraction)`` called with increasing fractions in (0, 1] (after the FFT, per
        chunk of columns, at the end). Not a k-Wave option.
    dtype : float64 or float32, optional
        float64 (k-Wave's precision) or float32 (working precision and output; half the
        memory, relative error ~1e-6). Not a k-Wave option.

    Returns
    -------
    ndarray, shape ``(N_t, N_y)``
        p0 of ``dtype``, row i at depth i c dt (row 0 on the sensor line).

    Raises
    ------
    ValueError
        NaN/inf, wrong ndim, non-positive dy/dt/c, unknown data_order/interp.

    References
    ----------
    .. [1] B. E. Treeby, B. T. Cox, "k-Wave: MATLAB toolbox for the simulation and
       reconstruction of photoacoustic wave fields", J. Biomed. Opt. 15 (2010);
       ``kspaceLineRecon.m`` (k-Wave commit 0f1a70f, ``shared/reference/KWAVE_RECON_NOTES.md``).

    Examples
    --------
    >>> import numpy as np
    >>> from driver.physics.forward import forward_grid
    >>> from service.recon.kwave import kspace_line_recon
    >>> p0 = np.zeros((16, 32))  # a point source at depth row 8, pitch 0.1 mm
    >>> p0[8, 16] = 1.0
    >>> data = forward_grid(p0, dx=1e-4, dz=1e-4, dt=1e-4 / 1500, n_t=40, c=1500.0)  # (N_t, N_y)
    >>> img = kspace_line_recon(data, 1e-4, 1e-4 / 1500, 1500.0)  # rows c dt = 0.1 mm apart
    >>> img.shape, img.dtype, np.unravel_index(img.argmax(), img.shape)
    ((40, 32), dtype('float64'), (np.int64(8), np.int64(16)))
    """
    p = checks.finite_array("p", p, (2,))
    if data_order not in ("ty", "yt"):
        raise ValueError(f"data_order must be 'ty' or 'yt', got {data_order!r}")
    if data_order == "yt":
        p = p.T
    dy, dt, c = (checks.positive(n, v) for n, v in (("dy", dy), ("dt", dt), ("c", c)))
    return _recon(p, dt, c, (dy,), interp, pos_cond, dtype=dtype, progress=progress)


def kspace_plane_recon(p: npt.ArrayLike, dy: float, dz: float, dt: float, c: float, data_order: str = "tyz",
                       interp: str = "*nearest", pos_cond: bool = False, progress: Fraction | None = None,
                       dtype: npt.DTypeLike = np.float64) -> np.ndarray:
    """3-D planar reconstruction exactly as k-Wave's ``kspacePlaneRecon``.

    Parameters
    ----------
    p : ndarray, shape ``(N_t, N_y, N_z)`` for ``data_order='tyz'`` or ``(N_y, N_z, N_t)`` for ``'yzt'``
        Pressure, Pa; sample 0 at t = 0. (k-Wave's y and z are the two lateral axes.)
    dy, dz : float
        Sensor spacings along the two lateral axes, m.
    dt, c, interp, pos_cond, progress, dtype
        As `kspace_line_recon` (dt in s, c in m/s).
    data_order : {"tyz", "yzt"}, optional
        Axis order of ``p``.

    Returns
    -------
    ndarray, shape ``(N_t, N_y, N_z)``
        p0 of ``dtype``, plane i at depth i c dt.

    Raises
    ------
    ValueError
        As `kspace_line_recon`.

    References
    ----------
    .. [1] B. E. Treeby, B. T. Cox, "k-Wave: MATLAB toolbox for the simulation and
       reconstruction of photoacoustic wave fields", J. Biomed. Opt. 15 (2010);
       ``kspacePlaneRecon.m`` (k-Wave commit 0f1a70f, ``shared/reference/KWAVE_RECON_NOTES.md``).

    Examples
    --------
    >>> import numpy as np
    >>> from driver.physics.forward import forward_grid
    >>> from service.recon.kwave import kspace_plane_recon
    >>> p0 = np.zeros((8, 8, 8))  # (n_z, n_y, n_x), a point source in the middle
    >>> p0[4, 4, 4] = 1.0
    >>> data = forward_grid(p0, 1e-4, 1e-4, 1e-4 / 1500, 24, 1500.0)  # (N_t, N_y, N_z)
    >>> img = kspace_plane_recon(data, 1e-4, 1e-4, 1e-4 / 1500, 1500.0)
    >>> img.shape, np.unravel_index(img.argmax(), img.shape)
    ((24, 8, 8), (np.int64(4), np.int64(4), np.int64(4)))
    """
    p = checks.finite_array("p", p, (3,))
    if data_order not in ("tyz", "yzt"):
        raise ValueError(f"data_order must be 'tyz' or 'yzt', got {data_order!r}")
    if data_order == "yzt":
        p = np.transpose(p, (2, 0, 1))
    dy, dz, dt, c = (checks.positive(n, v) for n, v in (("dy", dy), ("dz", dz), ("dt", dt), ("c", c)))
    return _recon(p, dt, c, (dy, dz), interp, pos_cond, dtype=dtype, progress=progress)
