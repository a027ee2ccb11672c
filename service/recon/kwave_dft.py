"""The DFT engine of k-Wave's modes (`fpscan.service.recon.kwave`): the transforms of k-Wave's
`kspaceLineRecon` / `kspacePlaneRecon` at k-Wave's own lengths, as real matrix products
(BLAS, in threads of our own) where those beat the FFT.

What `fpscan.service.recon.kwave` takes from here, and nothing of k-Wave's algorithm itself (the
grids, the scaling, the k-space mapping, its interpolation and numba kernel stay there):

- `lateral_forward` / `lateral_inverse`: the lateral real DFT of the data (time first) and
  its inverse, the real axis as a matrix product at lengths with a large prime factor
  (`product_length`: 226 = 2·113, the paper's scan), an FFT otherwise; the inverse written
  over the spectrum's own memory.
- `even_transforms`: the time -> depth step, in place. k-Wave's mirrored series is even, so
  its DFT of odd length 2 N - 1 is a real-even (cosine) transform of N samples: one real
  matrix product each way up to `MATRIX_MAX_N` samples (BLAS beats the FFT at k-Wave's odd
  lengths there); above it, two smaller products by the prime-factor algorithm where
  2 N - 1 splits into coprime factors (`_EvenPFA`: 2047 = 23·89 at k-Wave's 1024 samples,
  up to `PFA_MAX_SUM`), else FFTs of the mirrored series. The caller's k-space mapping
  runs between the two transforms, per chunk of columns.

The products run in threads of our own with BLAS at one thread in each (threadpoolctl,
`_products_in_threads`): OpenBLAS's own threads spin after a product and slowed the
compiled kernels that follow. Timings: docs/history/measurements.md, "threads that stop spinning, and
k-Wave's even transforms as products".
"""
from __future__ import annotations

import contextlib
import functools
import math
import threading
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt
import scipy.fft

from fpscan.physics import fft_engine
from fpscan.physics.fast_lengths import largest_prime_factor
from fpscan.physics.lateral import irfft_lateral
from fpscan.service.progress import Fraction

if TYPE_CHECKING:
    from concurrent.futures import Executor

    from threadpoolctl import ThreadpoolController

__all__ = ["MATRIX_MAX_N", "PFA_MAX_SUM", "PRODUCT_MAX_N", "ColumnMapping", "product_length", "lateral_forward",
           "lateral_inverse", "even_transforms"]

# k-Wave's mirrored series is even, so its DFT of odd length M = 2 N - 1 (k-Wave's; 511 =
# 7·73, 2047 = 23·89: often a large prime factor) is the real-even transform
# y_k = a_0 + 2 Σ_{n=1}^{N-1} a_n cos(2π k n / M), k = 0..N-1 (`_even_matrix`). Up to this N
# it runs as a real matrix product (BLAS) per chunk of columns, above it as the FFT of the
# mirrored series. Per output point, 2 cores, float64
# (docs/history/measurements.md, "k-Wave's even transforms as products"): the product 7 ns at N = 128, 13 ns at 256, 19 ns at 384, 24 ns at
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
    complex point against the mirrored FFT's 32 ns (docs/history/measurements.md, "k-Wave's modes at the
    paper's size reach 2.0").

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
    return scipy.fft.fft(buf, axis=0, overwrite_x=True, workers=fft_engine.workers())[:n]


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


#: the k-space mapping `even_transforms` runs between its two transforms: ``mapping(P, c0, c1, out)``
#: writes into ``out`` (N, c1 - c0) the mapped spectrum of the columns c0:c1, ``P`` (N, c1 - c0)
#: their transform along time (the ω >= 0 half), both complex, time first
ColumnMapping = Callable[[np.ndarray, int, int, np.ndarray], None]


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
    (docs/history/measurements.md, "k-Wave's modes at the paper's size reach 2.0"), float64, FFT / product: n = 97 11.0 / 4.5 ns, 226 = 2·113 8.7 / 6.0,
    302 = 2·151 10.8 / 7.7, 454 = 2·227 15.3 / 10.9; but 518 = 14·37 3.8 / 12.3; float32
    about half of each.

    Parameters
    ----------
    n : int
        The lateral length (samples along the scan's last lateral axis).

    Returns
    -------
    bool
        True where `lateral_forward` / `lateral_inverse` (k-Wave's modes, `fpscan.service.recon.kwave`)
        take that axis's real DFT and its inverse as matrix products (for arrays above
        `fpscan.physics.fft_engine.SMALL_ELEMENTS`).

    Examples
    --------
    >>> from fpscan.service.recon.kwave_dft import product_length
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


def lateral_forward(p: np.ndarray, lat_axes: tuple[int, ...]) -> np.ndarray:
    """The lateral real DFT of k-Wave's data: ``scipy.fft.rfftn(p, axes=lat_axes)``, the real
    axis (the last) as a matrix product where `product_length` says so (a large array only).

    Parameters
    ----------
    p : ndarray, real (float32 or float64), shape ``(N_t, N_y)`` or ``(N_t, N_y, N_z)``
        Time first; the lateral axes after it.
    lat_axes : tuple of int
        The lateral axes, the real one last: ``(1,)`` or ``(1, 2)``.

    Returns
    -------
    ndarray, complex64 or complex128 (following ``p``), shape ``p.shape[:-1] + (n // 2 + 1,)``
        The half spectrum along the last axis (n = ``p.shape[-1]``), full along the others;
        C-contiguous on the product path.

    Examples
    --------
    >>> import numpy as np, scipy.fft
    >>> from fpscan.service.recon.kwave_dft import lateral_forward
    >>> p = np.random.default_rng(0).standard_normal((300, 226))  # 226 = 2·113: a product
    >>> A = lateral_forward(p, (1,))
    >>> A.shape, A.dtype, np.allclose(A, scipy.fft.rfft(p, axis=1))
    ((300, 114), dtype('complex128'), True)
    """
    n = p.shape[-1]
    if fft_engine.is_small(p.size):
        return scipy.fft.rfftn(p, axes=lat_axes, workers=fft_engine.workers())
    if not product_length(n):  # rfftn's second pass would take an array of its own: in place here
        out = scipy.fft.rfft(p, axis=-1, workers=fft_engine.workers())
        if len(lat_axes) == 2:
            out = scipy.fft.fft(out, axis=lat_axes[0], overwrite_x=True, workers=fft_engine.workers())
        return out
    W, _ = _lateral_matrices(n, p.dtype)
    rows = np.ascontiguousarray(p).reshape(-1, n)
    cdtype = np.complex64 if p.dtype == np.float32 else np.complex128
    out = np.empty(p.shape[:-1] + (n // 2 + 1,), dtype=cdtype)
    with _products_in_threads() as (_, matmul_rows):
        matmul_rows(W, rows, out.reshape(rows.shape[0], -1).view(p.dtype))
    if len(lat_axes) == 2:
        out = scipy.fft.fft(out, axis=lat_axes[0], overwrite_x=True, workers=fft_engine.workers())
    return out


def lateral_inverse(A: np.ndarray, lat_shape: tuple[int, ...], lat_axes: tuple[int, ...]) -> np.ndarray:
    """The inverse of `lateral_forward`: `fpscan.physics.lateral.irfft_lateral` (``A``
    consumed), the real axis as a matrix product where `product_length` says so (a large
    array only); the image is written over ``A``'s own memory (a view of it is returned).

    Parameters
    ----------
    A : ndarray, complex64 or complex128
        The half spectrum (`lateral_forward`'s layout), overwritten.
    lat_shape : tuple of int
        The lateral lengths of the result: ``(N_y,)`` or ``(N_y, N_z)``.
    lat_axes : tuple of int
        The lateral axes, the real one last: ``(1,)`` or ``(1, 2)``.

    Returns
    -------
    ndarray, float32 or float64 (following ``A``), shape ``A.shape[:1] + lat_shape``
        The real image, a view of ``A``'s memory where ``A`` is C-contiguous.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon.kwave_dft import lateral_forward, lateral_inverse
    >>> p = np.random.default_rng(0).standard_normal((300, 226))
    >>> back = lateral_inverse(lateral_forward(p, (1,)), (226,), (1,))
    >>> back.shape, np.allclose(back, p)
    ((300, 226), True)
    """
    n = lat_shape[-1]
    rdtype = np.float32 if A.dtype == np.complex64 else np.float64
    if fft_engine.is_small(A.size // A.shape[-1] * n) or not product_length(n):  # the output's size
        over: np.ndarray | None = None
        if A.flags.c_contiguous and lat_axes[0] == 1:  # slab by slab over the spectrum (irfft_lateral's out)
            over = A.reshape(-1).view(rdtype)[: A.size // A.shape[-1] * n].reshape(A.shape[:-1] + (n,))
        return irfft_lateral(A, lat_shape, lat_axes, out=over)
    if len(lat_axes) == 2:
        A = scipy.fft.ifft(A, axis=lat_axes[0], overwrite_x=True, workers=fft_engine.workers())
    _, V = _lateral_matrices(n, np.dtype(rdtype))
    rows = np.ascontiguousarray(A).reshape(-1, A.shape[-1]).view(rdtype)
    out = rows.reshape(-1)[: rows.shape[0] * n].reshape(rows.shape[0], n)  # over the spectrum
    with _products_in_threads() as (_, matmul_rows):
        matmul_rows(V, rows, out, over=True)
    return out.reshape(A.shape[:-1] + (n,))


_CHUNK_BYTES = 8 << 20  # the product path's columns per chunk: 8 MiB of spectrum (2048 at N = 256)


def _by_products(a: np.ndarray, mapping: ColumnMapping, scale: float, rdtype: np.dtype, progress: Fraction | None,
                 split: tuple[int, int] | None = None) -> None:
    """`even_transforms` by products, in place in ``a`` (N, cols), time first: per
    chunk of columns the real-even transform along time (a product with `_even_matrix`, or
    with a coprime ``split`` of 2 N - 1 the prime-factor algorithm `_EvenPFA`), the
    mapping, the transform along depth (the same, times ``scale``, folded into its matrix). Chunks of `_CHUNK_BYTES`: the
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


def _by_ffts(a: np.ndarray, mapping: ColumnMapping, scale: float, rdtype: np.dtype, progress: Fraction | None) -> None:
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


def even_transforms(a: np.ndarray, mapping: ColumnMapping, scale: float, dtype: np.dtype,
                    progress: Fraction | None = None) -> None:
    """The time -> depth step of k-Wave's algorithm, in place: the DFT along time of the
    mirrored (even) series of each column of ``a``, the caller's k-space ``mapping``, the
    inverse DFT along depth, each on the non-negative half only (N of the mirrored
    series' M = 2 N - 1 points). Per chunk of columns: a product with the real-even matrix
    up to `MATRIX_MAX_N` samples; above it the prime-factor algorithm where M has a coprime
    split of sum <= `PFA_MAX_SUM`; else FFTs of the mirrored series. The numbers are the
    same to rounding on every path.

    Parameters
    ----------
    a : ndarray, complex64 or complex128, shape ``(N, n_cols)``, C-contiguous
        Time first, one lateral column (of the lateral spectrum) per column; overwritten with
        the result: ``scale`` times the inverse transform (the unnormalised sum, no 1 / M) of
        the mapped spectrum.
    mapping : callable
        ``mapping(P, c0, c1, out)`` (`ColumnMapping`): writes the mapped spectrum of the
        columns c0:c1 into ``out`` from their forward transform ``P`` (both
        ``(N, c1 - c0)``, ``a``'s dtype); called once per chunk, chunks in order.
    scale : float
        Factor of the inverse transform (k-Wave's modes pass 1 / M times the image's 4 / c).
    dtype : numpy.dtype
        The real dtype of ``a`` (float32 or float64): the products' precision.
    progress : callable, optional
        ``progress(fraction)`` called with increasing fractions in (0, 1] as each chunk ends.

    Returns
    -------
    None
        ``a`` holds the result.

    Examples
    --------
    With the identity mapping and ``scale = 1 / M`` the step is a round trip, by products
    (N = 40) and by the prime-factor algorithm (N = 409: M = 817 = 19·43):

    >>> import numpy as np
    >>> from fpscan.service.recon.kwave_dft import even_transforms
    >>> def identity(P, c0, c1, out): out[:] = P
    >>> for n in (40, 409):
    ...     a = np.random.default_rng(n).standard_normal((n, 6)) + 0j
    ...     b = a.copy()
    ...     even_transforms(b, identity, 1 / (2 * n - 1), np.dtype(np.float64))
    ...     print(n, np.allclose(b, a))
    40 True
    409 True
    """
    n = a.shape[0]
    split = None if n <= MATRIX_MAX_N else _coprime_split(2 * n - 1)
    if n <= MATRIX_MAX_N or (split is not None and sum(split) <= PFA_MAX_SUM):
        _by_products(a, mapping, scale, dtype, progress, split)
    else:
        _by_ffts(a, mapping, scale, dtype, progress)
