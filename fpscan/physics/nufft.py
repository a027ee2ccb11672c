"""The temporal step of planar PAT: even-extended time series <-> non-uniform frequencies.

For every lateral wavenumber column (one lateral k per column, ``|k_lat|^2`` given) the
reconstruction needs, at the non-equispaced temporal frequencies
``omega_l = c * sqrt(|k_lat|^2 + kz_l^2)``, the transform of the data extended evenly in
time (Xu, Feng & Wang 2002; the paper, eq. (1))::

    E(omega) = sum_n a_n * 2 cos(omega * t_n),   t_n = t0 + n dt
             = exp(-i omega t0) S(theta) + exp(+i omega t0) S(-theta),
    S(theta) = sum_{n=0}^{N-1} a_n exp(-i n theta),   theta = omega * dt

(with a_0 halved when t0 = 0, so the t = 0 sample is counted once). The forward model
needs the adjoint: g_n = sum_l b_l cos(omega_l t_n).

Two ways to evaluate S(theta) are offered (``kind``):

- ``"nufft"`` (NER-NUFFT, paper §3.1, Fourmont 2003; kernel and parameters of FINUFFT,
  Barnett et al. 2019): S is a 1-D type-2 NUFFT. The centred coefficients are divided by
  the kernel's Fourier transform, zero-padded to an oversampled grid of L >= 2 M points,
  FFT'd, and interpolated at theta with the w-tap "exponential of semicircle" kernel
  phi(u) = exp(beta (sqrt(1 - (2u/w)^2) - 1)), w = ceil(-log10(eps/10)), beta = 2.30 w.
  Relative error ~ eps.
- ``"linear"``, ``"nearest"`` (k-Wave style, FFT on the regular frequency grid): S on
  the DFT grid of the mirrored series (L = 2N - 1, what kspaceLineRecon's mirroring gives,
  rounded up to a fast length: `fpscan.physics.fast_lengths`) and interpolated linearly /
  by the nearest node (ties to the upper node).

The interpolation runs in one compiled loop (numba, `fpscan.physics.nufft_kernels`) over
groups of columns that share ``|k_lat|^2`` (the taps depend on nothing else), so kernel
values are computed once per group. A small transform (`fpscan.physics.fft_engine.is_small`:
a tiny image, a quick look) runs the same arithmetic in numpy instead, so that it needs
neither numba nor scipy.fft (their imports and numba's cache load cost a fresh interpreter
about 1.5 s, many times such a reconstruction).
"""
from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt

from fpscan.physics import fft_engine, workspace
from fpscan.physics.grid_sizes import KINDS, grid_length, kernel_params
from fpscan.physics.step_times import step

__all__ = [
    "KINDS", "TemporalGrid", "kernel_params", "es_kernel", "kernel_polynomials", "grid_length", "make_grid",
    "transpose", "gather_columns", "scatter_columns", "to_fine_grid", "from_fine_grid", "scatter_fine_grid",
    "group_columns",
    "evaluate", "spread", "group_tap_arrays",
]

_KIND_CODE = {"nufft": 0, "linear": 1, "nearest": 2}


def _compiled() -> ModuleType:
    """The numba kernels (imported on first use: numba's import costs start-up time)."""
    from fpscan.physics import nufft_kernels

    return nufft_kernels


@dataclass(frozen=True)
class TemporalGrid:
    """Geometry of the oversampled temporal grid for one transform (made by :func:`make_grid`).

    Attributes
    ----------
    n_t : int
        Samples per series.
    kind : str
        One of ``KINDS`` (module doc).
    L : int
        Fine-grid length (samples).
    shift : int
        The centring offset M/2 (nufft) or 0.
    w : int
        Kernel width (taps).
    beta : float
        Kernel shape.
    phihat : ndarray ``(n_t,)``
        Kernel Fourier weights used to pre-/post-correct the coefficients (nufft) or ones.
    horner : ndarray ``(w, degree + 1)``
        Polynomial coefficients of the w taps (:func:`kernel_polynomials`; nufft) or a
        ``(1, 1)`` placeholder.

    Examples
    --------
    >>> from fpscan.physics.nufft import make_grid
    >>> grid = make_grid(100)
    >>> grid.L, grid.shift, grid.w, grid.phihat.shape
    (200, 50, 7, (100,))
    """

    n_t: int
    kind: str
    L: int
    shift: int
    w: int
    beta: float
    phihat: np.ndarray
    horner: np.ndarray


def es_kernel(u: np.ndarray, beta: float) -> np.ndarray:
    """The "exponential of semicircle" kernel (FINUFFT; Barnett, Magland & af Klinteberg,
    SIAM J. Sci. Comput. 41 (2019)) at normalised offsets ``u`` (any shape; the support is
    ``|u| <= 1``, zero outside): ``phi(u) = exp(beta (sqrt(1 - u²) - 1))``. The one place
    the temporal kernel's formula is written (its polynomial taps and its Fourier transform
    both evaluate it).

    Parameters
    ----------
    u : ndarray, any shape; offsets normalised to the kernel's half width (dimensionless).
    beta : float, the shape (:func:`kernel_params`).

    Returns
    -------
    ndarray, the shape of ``u``, float64 in [0, 1] (1 at u = 0).

    References
    ----------
    .. [1] A. H. Barnett, J. Magland, L. af Klinteberg, "A parallel nonuniform fast Fourier
       transform library based on an 'exponential of semicircle' kernel", SIAM J. Sci.
       Comput. 41 (2019) (the ES kernel).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import es_kernel
    >>> es_kernel(np.array([0.0, 1.0, 1.5]), beta=16.1)  # exp(-beta) at the edge, 0 beyond
    array([1.00000000e+00, 1.01826037e-07, 0.00000000e+00])
    """
    u = np.asarray(u, dtype=np.float64)
    inside = np.abs(u) <= 1.0
    return np.where(inside, np.exp(beta * (np.sqrt(np.clip(1.0 - u * u, 0.0, None)) - 1.0)), 0.0)


def kernel_polynomials(w: int, beta: float) -> np.ndarray:
    """The ES kernel's w taps as polynomials of the grid offset, for evaluation by Horner's
    rule instead of one square root and one exponential per tap (FINUFFT's approach,
    Barnett, Magland & af Klinteberg 2019, §5.1).

    With the first tap at ``base = ceil(s - w/2)`` for a point at fine-grid position
    ``s``, tap k sits at ``u_k = (x + k - w/2)·2/w`` with ``x = base - s + w/2`` in [0, 1);
    row k of the result holds the coefficients (highest degree first) of the polynomial in
    ``t = 2x - 1`` that approximates ``phi(u_k) = exp(beta (sqrt(1 - u_k²) - 1))``: a
    Chebyshev fit of degree w + 4 at 200 nodes. Its error is about eps/30 of the kernel's
    own tolerance (the square root's edge limits it), e.g. 4e-8 at w = 7 (eps 1e-6).

    Parameters
    ----------
    w : int, taps (:func:`kernel_params`).
    beta : float, the kernel's shape.

    Returns
    -------
    ndarray ``(w, w + 5)`` float64, highest degree first (``np.polyval`` order).

    References
    ----------
    .. [1] A. H. Barnett, J. Magland, L. af Klinteberg, "A parallel nonuniform fast Fourier
       transform library based on an 'exponential of semicircle' kernel", SIAM J. Sci.
       Comput. 41 (2019), §5.1.

    Examples
    --------
    The middle tap (k = 3 of 7) of a point on a grid node (x = 1/2, t = 0) is the kernel's
    peak.

    >>> import numpy as np
    >>> from fpscan.physics.nufft import kernel_params, kernel_polynomials
    >>> taps = kernel_polynomials(*kernel_params(1e-6))
    >>> taps.shape, round(float(np.polyval(taps[3], 0.0)), 9)
    ((7, 12), 1.0)
    """
    from numpy.polynomial import chebyshev

    t = np.cos(np.pi * (np.arange(200) + 0.5) / 200)
    x = 0.5 * (t + 1.0)
    rows = []
    for k in range(w):
        u = (x + k - 0.5 * w) * (2.0 / w)
        phi = es_kernel(u, beta)
        coef = chebyshev.cheb2poly(chebyshev.chebfit(t, phi, w + 4))
        # cheb2poly drops a highest coefficient that cancels to exactly 0 (numpy 2.4): keep w + 5
        rows.append(np.pad(coef, (0, w + 5 - len(coef)))[::-1])
    return np.ascontiguousarray(rows, dtype=np.float64)


def _kernel_fourier(w: int, beta: float, k: np.ndarray) -> np.ndarray:
    """phi_hat(k) = int_{-w/2}^{w/2} phi(u) cos(k u) du by Gauss-Legendre quadrature."""
    nodes, weights = np.polynomial.legendre.leggauss(4 * w + 40)
    u = nodes * (w / 2.0)
    phi = es_kernel(2.0 * u / w, beta)
    return (np.cos(np.outer(k, u)) @ (phi * weights)) * (w / 2.0)


@functools.lru_cache(maxsize=32)
def make_grid(n_t: int, kind: str = "nufft", eps: float = 1e-6) -> TemporalGrid:
    """Plan the temporal transform for series of ``n_t`` samples (see module doc).
    Cached (iterative solvers apply the same transform many times); the returned
    grid and its ``phihat`` are read-only.

    Parameters
    ----------
    n_t : int >= 1, samples per series.
    kind : one of ``KINDS``.
    eps : float, tolerance of the nufft kind.

    Returns
    -------
    TemporalGrid

    Raises
    ------
    ValueError
        A bad kind, n_t or eps.

    Examples
    --------
    >>> from fpscan.physics.nufft import make_grid
    >>> make_grid(100) is make_grid(100)  # planned once
    True
    >>> make_grid(100, "linear").w
    2
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    n_t = int(n_t)
    if n_t < 1:
        raise ValueError("n_t must be >= 1")
    if kind == "nufft":
        w, beta = kernel_params(eps)
        M = n_t + (n_t % 2)
        L = grid_length(n_t, kind, eps)
        h = 2.0 * np.pi / L
        m = np.arange(n_t) - M // 2
        phihat = _kernel_fourier(w, beta, m * h)
        phihat.setflags(write=False)
        horner = kernel_polynomials(w, beta)
        horner.setflags(write=False)
        return TemporalGrid(n_t, kind, L, M // 2, w, beta, phihat, horner)
    L = grid_length(n_t, kind, eps)
    ones = np.ones(n_t)
    ones.setflags(write=False)
    return TemporalGrid(n_t, kind, L, 0, 2 if kind == "linear" else 1, 0.0, ones, np.zeros((1, 1)))


def gather_columns(A: np.ndarray, cols: np.ndarray, out: np.ndarray) -> None:
    """out[c, j] = A[j, cols[c]]: chosen columns of a 2-D array, transposed, in
    cache-friendly tiles (parallel; no copy of the chosen columns first): the compiled
    ``place_columns`` with unit scale and no shift.

    Parameters
    ----------
    A : ndarray ``(n_j, n_a)``.
    cols : ndarray ``(n_c,)`` int64, column indices into ``A``.
    out : ndarray ``(n_c, n_j)``, written in place (any dtype ``A`` converts to).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import gather_columns
    >>> out = np.empty((2, 3))
    >>> gather_columns(np.arange(12.0).reshape(3, 4), np.array([3, 1]), out)
    >>> out
    array([[ 3.,  7., 11.],
           [ 1.,  5.,  9.]])
    """
    unit = np.ones(A.shape[0], dtype=out.real.dtype)
    _compiled().place_columns(A, np.asarray(cols, dtype=np.int64), unit, 0, out.shape[1], out)


def scatter_columns(F: np.ndarray, cols: np.ndarray, out: np.ndarray) -> None:
    """out[j, cols[c]] = F[c, j]: the transpose of `gather_columns`, rows of ``F`` written
    to chosen columns of ``out`` (distinct ``cols``), in cache-friendly tiles (parallel).

    Parameters
    ----------
    F : ndarray ``(n_c, n_j)``.
    cols : ndarray ``(n_c,)`` int64, distinct column indices into ``out``.
    out : ndarray ``(n_j, n_a)``, written in place at those columns.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import scatter_columns
    >>> out = np.zeros((3, 4))
    >>> scatter_columns(np.array([[3.0, 7.0, 11.0], [1.0, 5.0, 9.0]]), np.array([3, 1]), out)
    >>> out
    array([[ 0.,  1.,  0.,  3.],
           [ 0.,  5.,  0.,  7.],
           [ 0.,  9.,  0., 11.]])
    """
    _compiled().scatter_columns(F, np.asarray(cols, dtype=np.int64), out)


def transpose(F: np.ndarray, out: np.ndarray) -> None:
    """out[j, c] = F[c, j] for 2-D arrays, in cache-friendly tiles (parallel; `scatter_columns`
    to every column; a small array: numpy's copy of the transposed view).

    Parameters
    ----------
    F : ndarray ``(n_c, n_j)``.
    out : ndarray ``(n_j, n_c)``, written in place (any dtype ``F`` converts to).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import transpose
    >>> out = np.empty((3, 2))
    >>> transpose(np.arange(6.0).reshape(2, 3), out)
    >>> out
    array([[0., 3.],
           [1., 4.],
           [2., 5.]])
    """
    if fft_engine.is_small(F.size):
        out[...] = F.T
    else:
        _compiled().scatter_columns(F, np.arange(F.shape[0], dtype=np.int64), out)


def to_fine_grid(A: np.ndarray, grid: TemporalGrid, t0_is_zero: bool,
                 columns: np.ndarray | None = None) -> np.ndarray:
    """(n_t, n_cols) coefficients (time first, as a lateral FFT of the data leaves them)
    -> (n_cols, L) values of S on the fine theta grid, one column per row.

    ``A`` is not modified. The t = 0 sample is halved when ``t0_is_zero``. A small transform
    (`fpscan.physics.fft_engine.is_small` of the fine grid) runs in numpy, a larger one in the
    compiled placement and scipy.fft.

    Parameters
    ----------
    A : ndarray ``(n_t, n_a)``, real or complex (float32/complex64 stay single precision).
    grid : TemporalGrid of ``n_t`` (:func:`make_grid`).
    t0_is_zero : bool, whether sample 0 is at t = 0.
    columns : ndarray ``(n_cols,)`` int, optional
        The columns of ``A`` to transform, in this order (default all: n_cols = n_a); read in
        place, not copied first.

    Returns
    -------
    ndarray ``(n_cols, grid.L)`` complex; a large one on memory of the work-array pool
    (`fpscan.physics.workspace`: reused by a later call once this array is dropped).

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
    >>> n_t, dt, c, t0 = 32, 1e-8, 1500.0, 1e-7  # samples, s, m/s, s
    >>> t = t0 + dt * np.arange(n_t)
    >>> kz = np.array([1e4, 5e4, 2e5])  # rad/m; one column with k_lat = 0: omega = c kz
    >>> grid = make_grid(n_t, "nufft", 1e-10)
    >>> to_fine_grid(np.ones((n_t, 2)), grid, t0_is_zero=False).shape  # (n_cols, L)
    (2, 64)
    """
    ctype = np.complex64 if A.dtype in (np.float32, np.complex64) else np.complex128
    cols = np.arange(A.shape[1], dtype=np.int64) if columns is None else np.asarray(columns, dtype=np.int64)
    with step("temporal placement"):
        scale = (1.0 / grid.phihat).astype(np.float32 if ctype == np.complex64 else np.float64)
        if t0_is_zero:
            scale = scale.copy()
            scale[0] *= 0.5
        # nufft: centred mode m = n - shift sits at fine index m mod L; FFT-grid kinds: shift 0
        if fft_engine.is_small(len(cols) * grid.L):
            U = np.zeros((len(cols), grid.L), dtype=ctype)
            U[:, (np.arange(A.shape[0]) - grid.shift) % grid.L] = (A[:, cols] * scale[:, None]).T
        else:  # on memory of an earlier call (`fpscan.physics.workspace`), every entry written
            U = workspace.take((len(cols), grid.L), ctype)
            _compiled().place_columns(np.ascontiguousarray(A, dtype=ctype), cols, scale, grid.shift, grid.L, U)
    with step("temporal FFT"):
        return fft_engine.fft(U, axis=-1, overwrite_x=True)


def from_fine_grid(R: np.ndarray, grid: TemporalGrid, t0_is_zero: bool, overwrite: bool = False) -> np.ndarray:
    """Adjoint of `to_fine_grid`: (n_cols, L) spread values -> (n_cols, n_t) series.

    Parameters
    ----------
    R : ndarray ``(n_cols, grid.L)`` complex (from :func:`spread`).
    grid : TemporalGrid.
    t0_is_zero : bool, whether sample 0 is at t = 0 (its weight is halved).
    overwrite : bool
        ``R`` may be overwritten (no second fine grid at the peak).

    Returns
    -------
    ndarray ``(n_cols, n_t)`` complex.

    Examples
    --------
    With :func:`spread` it computes the forward model's g_n = Σ_l b_l 2 cos(ω_l t_n):

    >>> import numpy as np
    >>> from fpscan.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
    >>> n_t, dt, c, t0 = 32, 1e-8, 1500.0, 1e-7  # samples, s, m/s, s
    >>> t = t0 + dt * np.arange(n_t)
    >>> kz = np.array([1e4, 5e4, 2e5])  # rad/m; one column with k_lat = 0: omega = c kz
    >>> grid = make_grid(n_t, "nufft", 1e-10)
    >>> b = np.array([[1.0, 0.5, -0.25]], dtype=complex)  # (n_cols, n_kz)
    >>> g = from_fine_grid(spread(b, grid, np.zeros(1), kz, np.ones(3), c, dt, t0), grid, False)
    >>> bool(np.allclose(g[0], 2 * np.cos(np.outer(t, c * kz)) @ b[0], atol=1e-8))
    True
    """
    n_t = grid.n_t
    # adjoint of the forward FFT (no 1/L)
    import scipy.fft  # the forward model and the model-based operator only: never small

    V = scipy.fft.ifft(R, axis=-1, workers=fft_engine.workers(), norm="forward", overwrite_x=overwrite)
    scale = (1.0 / grid.phihat).astype(V.real.dtype)
    if t0_is_zero:
        scale = scale.copy()
        scale[0] *= 0.5
    out = np.empty((R.shape[0], n_t), dtype=V.dtype)
    if grid.kind == "nufft":
        s = grid.shift
        out[:, s:] = V[:, : n_t - s]
        out[:, :s] = V[:, grid.L - s :]
    else:
        out[:] = V[:, :n_t]
    out *= scale
    return out


def scatter_fine_grid(R: np.ndarray, grid: TemporalGrid, t0_is_zero: bool, cols: np.ndarray, out: np.ndarray) -> None:
    """`from_fine_grid` (overwriting ``R``) written into chosen columns of a time-first array, in
    one pass on every core: ``out[:, cols] = from_fine_grid(R).T``, without the (n_cols, n_t)
    array between them.

    Parameters
    ----------
    R : ndarray ``(n_cols, grid.L)`` complex, C-contiguous (from :func:`spread`); overwritten.
    grid : TemporalGrid (kind ``"nufft"``).
    t0_is_zero : bool, whether sample 0 is at t = 0 (its weight is halved).
    cols : ndarray ``(n_cols,)`` int, distinct columns of ``out``.
    out : ndarray ``(grid.n_t, n_all)`` complex of R's precision, written at ``cols``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import from_fine_grid, make_grid, scatter_fine_grid
    >>> grid = make_grid(32, "nufft", 1e-10)
    >>> R = np.random.default_rng(0).standard_normal((3, grid.L)).astype(complex)
    >>> out = np.zeros((32, 5), complex)
    >>> scatter_fine_grid(R.copy(), grid, False, np.array([4, 0, 2]), out)
    >>> bool(np.array_equal(out[:, [4, 0, 2]], from_fine_grid(R, grid, False).T))
    True
    """
    import scipy.fft

    V = scipy.fft.ifft(R, axis=-1, workers=fft_engine.workers(), norm="forward", overwrite_x=True)
    scale = (1.0 / grid.phihat).astype(V.real.dtype)
    if t0_is_zero:
        scale = scale.copy()
        scale[0] *= 0.5
    shift = grid.shift if grid.kind == "nufft" else 0
    _compiled().unplace_columns(V, np.asarray(cols, dtype=np.int64), scale, shift, out)


def group_columns(klat2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group columns with equal |k_lat|^2 (to 1e-12 relative).

    Parameters
    ----------
    klat2 : ndarray, any shape (raveled: ``(n_cols,)``); |k_lat|² of each column, rad²/m².

    Returns
    -------
    group_values : ndarray ``(n_groups,)``, ascending.
    group_ptr : ndarray ``(n_groups + 1,)`` int64.
    order : ndarray ``(n_cols,)`` int64
        The columns of group g are ``order[group_ptr[g]:group_ptr[g + 1]]``.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import group_columns
    >>> values, ptr, order = group_columns(np.array([1.0, 4.0, 1.0, 0.0]))
    >>> values, ptr, order
    (array([0., 1., 4.]), array([0, 1, 3, 4]), array([3, 0, 2, 1]))
    """
    k = np.asarray(klat2, dtype=np.float64).ravel()
    scale = max(float(k.max(initial=0.0)), 1e-300)
    key = np.round(k / scale * 1e12)
    uniq, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    counts = np.bincount(inverse, minlength=len(uniq))
    ptr = np.concatenate([[0], np.cumsum(counts)])
    return k[first], ptr.astype(np.int64), order.astype(np.int64)


def evaluate(
    U: np.ndarray,
    grid: TemporalGrid,
    klat2: np.ndarray,
    kz: np.ndarray,
    qw: np.ndarray,
    c: float,
    dt: float,
    t0: float,
    inversion: bool,
    out_dtype: npt.DTypeLike | None = None,
    progress: Callable[[float], object] | None = None,
    n_chunks: int = 8,
    groups: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Evaluate the even-extended transform of every column at omega = c |k|.

    U : (n_cols, L) from `to_fine_grid`. klat2 : (n_cols,) |k_lat|^2 in rad^2/m^2.
    kz : (n_kz,) depth wavenumbers in rad/m (ascending when inversion). qw : (n_kz,) weights per kz.
    inversion=True multiplies by qw * kz/omega (1/c at omega = 0) and zeroes omega above
    the temporal Nyquist pi/dt; False multiplies by qw only.
    progress: optional callable(fraction in (0, 1]) called after each of up to ``n_chunks``
    chunks of column groups (fewer for small transforms).
    groups: `group_columns` (klat2) when the caller keeps it (an operator applied many
    times); None: computed here.
    out: a C-contiguous (n_cols, n_kz) array of ``out_dtype`` (default U's) to write the
    result into, not overlapping U (memory the caller has already written: no fresh pages to
    fault in); None: a new one.
    Returns (n_cols, n_kz) complex. A small transform (U and the result together at most
    `fpscan.physics.fft_engine.SMALL_ELEMENTS`) runs in numpy (`_interp_small`: the same
    taps and sums), a larger one in the compiled kernel.

    Parameters
    ----------
    U : ndarray ``(n_cols, L)`` from :func:`to_fine_grid`.
    grid : TemporalGrid.
    klat2 : ndarray ``(n_cols,)``, |k_lat|² in rad²/m².
    kz : ndarray ``(n_kz,)``, depth wavenumbers in rad/m.
    qw : ndarray ``(n_kz,)``, weights per kz.
    c : float, m/s.  dt : float, s.  t0 : float, s (time of sample 0).
    inversion : bool, see above.
    out_dtype, progress, n_chunks, groups, out
        See above.

    Returns
    -------
    ndarray ``(n_cols, n_kz)`` complex.

    Raises
    ------
    ValueError
        ``inversion`` with kz not ascending; an ``out`` of the wrong shape, dtype or layout.

    References
    ----------
    .. [1] K. Fourmont, "Non-equispaced fast Fourier transforms with applications to
       tomography", J. Fourier Anal. Appl. 9 (2003).

    Examples
    --------
    The transform of the evenly extended series, E(ω) = Σ_n a_n 2 cos(ω t_n), against the
    direct sum:

    >>> import numpy as np
    >>> from fpscan.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
    >>> n_t, dt, c, t0 = 32, 1e-8, 1500.0, 1e-7  # samples, s, m/s, s
    >>> t = t0 + dt * np.arange(n_t)
    >>> kz = np.array([1e4, 5e4, 2e5])  # rad/m; one column with k_lat = 0: omega = c kz
    >>> grid = make_grid(n_t, "nufft", 1e-10)
    >>> a = np.random.default_rng(0).standard_normal((n_t, 1))  # (n_t, n_cols)
    >>> U = to_fine_grid(a, grid, t0_is_zero=False)
    >>> E = evaluate(U, grid, np.zeros(1), kz, np.ones(3), c, dt, t0, inversion=False)
    >>> bool(np.allclose(E[0], 2 * np.cos(np.outer(c * kz, t)) @ a[:, 0], atol=1e-8))
    True
    """
    gvals, gptr, order = group_columns(klat2) if groups is None else groups
    shape, dtype = (U.shape[0], len(kz)), np.dtype(out_dtype or U.dtype)
    if out is None:
        out = np.empty(shape, dtype=dtype)
    elif out.shape != shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous {shape} array of {dtype}, got {out.shape} {out.dtype}")
    kz = np.asarray(kz, np.float64)
    qw = np.asarray(qw, np.float64)
    if inversion and np.any(np.diff(kz) < 0):
        raise ValueError("kz must be ascending for the inversion (every kz after the first above the Nyquist is too)")
    if fft_engine.is_small(U.size + out.size):
        _interp_small(U, gvals, gptr, order, kz, qw, float(c), float(dt), float(t0), grid, bool(inversion), out)
        if progress is not None:
            progress(1.0)
        return out
    kernel = _compiled().interp_kernel
    for a, b in _group_chunks(len(gvals), n_chunks, U.shape[0] * len(kz), progress):
        kernel(U, gvals[a:b], gptr[a : b + 1], order, kz, qw, float(c), float(dt), float(t0),
               2.0 * np.pi / grid.L, grid.L, _KIND_CODE[grid.kind], grid.w, grid.horner,
               grid.shift, bool(inversion), out)
    return out


def _interp_small(U: np.ndarray, gvals: np.ndarray, gptr: np.ndarray, order: np.ndarray, kz: np.ndarray,
                  qw: np.ndarray, c: float, dt: float, t0: float, grid: TemporalGrid, inversion: bool,
                  out: np.ndarray) -> None:
    """`nufft_kernels.interp_kernel` in numpy, for a small transform (no compiler): the same
    taps (`nufft_kernels.group_taps`, per column group, float64) and the same sums, every
    column and kz at once. Memory: (n_cols, n_kz, w) weights, bounded by the caller's
    size test."""
    L, w = grid.L, grid.w
    b, wts, ar, ai = group_tap_arrays(np, grid, gvals, kz, qw, c, dt, t0, inversion)
    group = np.empty(len(order), np.int64)  # each column's group
    group[order] = np.repeat(np.arange(len(gvals)), np.diff(gptr))
    idx = (b.astype(np.int64)[group][:, :, None] + np.arange(w)) % L  # (n_cols, n_kz, w)
    rows = np.arange(len(group))[:, None, None]
    wc = np.moveaxis(wts, 0, -1)[group]
    p1 = (wc * U[rows, idx]).sum(axis=-1)  # S(+θ) and S(-θ)
    p2 = (wc * U[rows, (L - idx) % L]).sum(axis=-1)
    out[...] = ar[group] * (p1 + p2) - 1j * ai[group] * (p1 - p2)


def group_tap_arrays(xp: ModuleType, grid: TemporalGrid, gvals: Any, kz: Any, qw: Any, c: float, dt: float,
                     t0: float, inversion: bool) -> tuple[Any, Any, Any, Any]:
    """The taps of every column group at every kz as whole arrays on ``xp`` (``numpy``, or
    ``cupy`` for `fpscan.physics.temporal_xp`): the formulas of the compiled
    `nufft_kernels.group_taps`, in float64, for `_interp_small` and the GPU path alike.

    Parameters
    ----------
    xp : module
        ``numpy`` or ``cupy``; the arrays below are of it.
    grid : TemporalGrid
        Any kind (`make_grid`).
    gvals : array ``(n_groups,)``
        |k_lat|² of each column group, rad²/m².
    kz, qw : array ``(n_kz,)``
        Depth wavenumbers in rad/m (ascending for an inversion) and their weights.
    c, dt, t0 : float
        Sound speed (m/s), sample interval and time of sample 0 (s).
    inversion : bool
        Multiply by k_z/ω (1/c at ω = 0) and zero from the first kz above the temporal Nyquist
        π/dt on; else by ``qw`` only.

    Returns
    -------
    base : array ``(n_groups, n_kz)`` float64
        The first tap's fine-grid index, before wrapping modulo ``grid.L``.
    weights : array ``(w, n_groups, n_kz)`` float64
        The taps' weights (nufft: the polynomials of `kernel_polynomials`; linear: the
        fractions; nearest: ones).
    ar, ai : array ``(n_groups, n_kz)`` float64
        The weight times cos / sin of φ = shift θ + ω t0, the +θ evaluation's phase.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.physics.nufft import group_tap_arrays, make_grid
    >>> grid = make_grid(32, "nufft", 1e-10)
    >>> base, weights, ar, ai = group_tap_arrays(np, grid, np.zeros(1), np.array([0.0, 1e4]), np.ones(2),
    ...                                          1500.0, 1e-8, 0.0, False)
    >>> base.shape, weights.shape, bool(np.allclose(ar**2 + ai**2, 1.0))  # |qw e^{iφ}| = qw = 1
    ((1, 2), (11, 1, 2), True)
    """
    w, h = grid.w, 2.0 * np.pi / grid.L
    om = c * xp.sqrt(gvals[:, None] + kz[None, :] ** 2)  # (n_groups, n_kz) rad/s
    th = om * dt
    sc = xp.broadcast_to(qw, om.shape)
    if inversion:
        # k_z / omega (1/c at omega = 0); zero from the first kz above the temporal Nyquist on
        positive = om > 0.0
        sc = sc * xp.where(positive, kz / xp.where(positive, om, 1.0), 1.0 / c)
        sc = sc * (xp.cumprod((th <= np.pi * (1.0 + 1e-12)).astype(np.int8), axis=1) > 0)
    s = th / h
    if grid.kind == "nufft":
        b = xp.ceil(s - 0.5 * w)
        t = 2.0 * (b - s + 0.5 * w) - 1.0
        wts = xp.empty((w,) + s.shape)
        for k in range(w):  # the tap polynomials by Horner's rule (`kernel_polynomials`)
            row = xp.full(s.shape, float(grid.horner[k, 0]))
            for d in range(1, grid.horner.shape[1]):
                row = row * t + float(grid.horner[k, d])
            wts[k] = row
    elif grid.kind == "linear":
        b = xp.floor(s)
        wts = xp.stack([1.0 - (s - b), s - b])
    else:
        b = xp.floor(s + 0.5)
        wts = xp.ones((1,) + s.shape)
    ph = grid.shift * th + om * t0
    return b, wts, sc * xp.cos(ph), sc * xp.sin(ph)


def _group_chunks(n_groups: int, n_chunks: int, work: int,
                  progress: Callable[[float], object] | None = None) -> Iterator[tuple[int, int]]:
    """Ranges [a, b) of column groups, up to ``n_chunks`` of them and each of at least ~4M
    of ``work`` (coefficients: small transforms run in one parallel region); each column's
    result is the same whichever chunk holds it. ``progress(fraction)`` is called after each
    chunk (by the caller's loop, as the next range is asked for), so that a caller sees real
    progress through the longest step."""
    n_chunks = max(1, min(n_chunks, work // (1 << 22), n_groups))
    bounds = np.linspace(0, n_groups, n_chunks + 1).astype(np.int64)
    for i in range(n_chunks):
        a, b = int(bounds[i]), int(bounds[i + 1])
        if b > a:
            yield a, b
        if progress is not None:
            progress((i + 1) / n_chunks)


def spread(
    B: np.ndarray,
    grid: TemporalGrid,
    klat2: np.ndarray,
    kz: np.ndarray,
    qw: np.ndarray,
    c: float,
    dt: float,
    t0: float,
    groups: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    progress: Callable[[float], object] | None = None,
    n_chunks: int = 1,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Adjoint of `evaluate` with ``inversion=False``: (n_cols, n_kz) coefficients ->
    (n_cols, L) spread fine-grid values (input of `from_fine_grid`); ``groups`` as
    `evaluate`.

    Parameters
    ----------
    B : ndarray ``(n_cols, n_kz)`` complex.
    grid, klat2, kz, qw, c, dt, t0, groups
        As :func:`evaluate` (units rad²/m², rad/m, m/s, s).
    progress, n_chunks
        As :func:`evaluate`: ``progress(fraction)`` after each of up to ``n_chunks``
        chunks of column groups (default one chunk; chunks of at least ~4M
        coefficients). Each column is spread by one chunk, so the result does not depend
        on the chunking.
    out : ndarray ``(n_cols, grid.L)``, optional
        C-contiguous, of the result's dtype, to write the result into (every entry: its
        contents need not be zero); default a new array.

    Returns
    -------
    ndarray ``(n_cols, grid.L)`` complex (``out`` when given).

    Raises
    ------
    ValueError
        An ``out`` of the wrong shape, dtype or layout.

    Examples
    --------
    The adjoint identity <evaluate(a), b> = <a, from_fine_grid(spread(b))>:

    >>> import numpy as np
    >>> from fpscan.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
    >>> n_t, dt, c, t0 = 32, 1e-8, 1500.0, 1e-7  # samples, s, m/s, s
    >>> t = t0 + dt * np.arange(n_t)
    >>> kz = np.array([1e4, 5e4, 2e5])  # rad/m; one column with k_lat = 0: omega = c kz
    >>> grid = make_grid(n_t, "nufft", 1e-10)
    >>> a = np.random.default_rng(0).standard_normal((n_t, 1))
    >>> b = np.array([[1.0, 0.5, -0.25]], dtype=complex)
    >>> E = evaluate(to_fine_grid(a, grid, False), grid, np.zeros(1), kz, np.ones(3), c, dt, t0, False)
    >>> g = from_fine_grid(spread(b, grid, np.zeros(1), kz, np.ones(3), c, dt, t0), grid, False)
    >>> bool(np.isclose(np.vdot(b[0], E[0]), np.vdot(g[0], a[:, 0])))
    True
    """
    gvals, gptr, order = group_columns(klat2) if groups is None else groups
    ctype = np.complex64 if B.dtype == np.complex64 else np.complex128
    shape = (B.shape[0], grid.L)
    if out is None:
        R = np.zeros(shape, dtype=ctype)
    elif out.shape != shape or out.dtype != ctype or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous {shape} array of {np.dtype(ctype)}, got {out.shape} {out.dtype}")
    else:
        R = out
    kz = np.asarray(kz, np.float64)
    qw = np.asarray(qw, np.float64)
    for a, b in _group_chunks(len(gvals), n_chunks, B.shape[0] * len(kz), progress):
        _compiled().spread_kernel(B, gvals[a:b], gptr[a : b + 1], order, kz, qw, float(c), float(dt), float(t0),
                       2.0 * np.pi / grid.L, grid.L, _KIND_CODE[grid.kind], grid.w, grid.horner, grid.shift, R)
    return R
