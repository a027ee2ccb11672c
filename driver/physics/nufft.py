"""The temporal step of planar PAT: even-extended time series <-> non-uniform frequencies.

For every lateral wavenumber column (one lateral k per column, ``|k_lat|^2`` given) the
reconstruction needs, at the non-equispaced temporal frequencies
``omega_l = c * sqrt(|k_lat|^2 + kz_l^2)``, the transform of the data extended evenly in
time (DESIGN §3.1)::

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
  rounded up to a fast length: `driver.physics.fast_lengths`) and interpolated linearly /
  by the nearest node (ties to the upper node).

The interpolation runs in one compiled loop (numba) over groups of columns that share
``|k_lat|^2`` (the taps depend on nothing else), so kernel values are computed once per
group.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.fft

from driver.physics.grid_sizes import KINDS, grid_length, kernel_params

__all__ = [
    "KINDS", "TemporalGrid", "kernel_params", "es_kernel", "kernel_polynomials", "grid_length", "make_grid",
    "transpose", "gather_columns", "scatter_columns", "to_fine_grid", "from_fine_grid", "group_columns",
    "evaluate", "spread",
]

_KIND_CODE = {"nufft": 0, "linear": 1, "nearest": 2}


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
    >>> from driver.physics.nufft import make_grid
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
    >>> from driver.physics.nufft import es_kernel
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
    >>> from driver.physics.nufft import kernel_params, kernel_polynomials
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
    >>> from driver.physics.nufft import make_grid
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


@numba.njit(parallel=True, cache=True)
def _place_columns(A, cols, scale, shift, L, U):
    """U[c, (n - shift) mod L] = A[n, cols[c]] * scale[n], in cache-friendly tiles."""
    n_t = A.shape[0]
    n_cols = cols.shape[0]
    tile = 64
    n_blocks = (n_cols + tile - 1) // tile
    for b in numba.prange(n_blocks):
        c0 = b * tile
        c1 = min(c0 + tile, n_cols)
        for n0 in range(0, n_t, tile):
            n1 = min(n0 + tile, n_t)
            for c in range(c0, c1):
                col = cols[c]
                for n in range(n0, n1):
                    j = n - shift
                    if j < 0:
                        j += L
                    U[c, j] = A[n, col] * scale[n]


def gather_columns(A: np.ndarray, cols: np.ndarray, out: np.ndarray) -> None:
    """out[c, j] = A[j, cols[c]]: chosen columns of a 2-D array, transposed, in
    cache-friendly tiles (parallel; no copy of the chosen columns first): `_place_columns`
    with unit scale and no shift.

    Parameters
    ----------
    A : ndarray ``(n_j, n_a)``.
    cols : ndarray ``(n_c,)`` int64, column indices into ``A``.
    out : ndarray ``(n_c, n_j)``, written in place (any dtype ``A`` converts to).

    Examples
    --------
    >>> import numpy as np
    >>> from driver.physics.nufft import gather_columns
    >>> out = np.empty((2, 3))
    >>> gather_columns(np.arange(12.0).reshape(3, 4), np.array([3, 1]), out)
    >>> out
    array([[ 3.,  7., 11.],
           [ 1.,  5.,  9.]])
    """
    unit = np.ones(A.shape[0], dtype=out.real.dtype)
    _place_columns(A, np.asarray(cols, dtype=np.int64), unit, 0, out.shape[1], out)


@numba.njit(parallel=True, cache=True)
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
    >>> from driver.physics.nufft import scatter_columns
    >>> out = np.zeros((3, 4))
    >>> scatter_columns(np.array([[3.0, 7.0, 11.0], [1.0, 5.0, 9.0]]), np.array([3, 1]), out)
    >>> out
    array([[ 0.,  1.,  0.,  3.],
           [ 0.,  5.,  0.,  7.],
           [ 0.,  9.,  0., 11.]])
    """
    n_c, n_j = F.shape
    tile = 64
    n_blocks = (n_j + tile - 1) // tile
    for b in numba.prange(n_blocks):
        j0 = b * tile
        j1 = min(j0 + tile, n_j)
        for c0 in range(0, n_c, tile):
            c1 = min(c0 + tile, n_c)
            for j in range(j0, j1):
                for c in range(c0, c1):
                    out[j, cols[c]] = F[c, j]


def transpose(F: np.ndarray, out: np.ndarray) -> None:
    """out[j, c] = F[c, j] for 2-D arrays, in cache-friendly tiles (parallel; `scatter_columns`
    to every column).

    Parameters
    ----------
    F : ndarray ``(n_c, n_j)``.
    out : ndarray ``(n_j, n_c)``, written in place (any dtype ``F`` converts to).

    Examples
    --------
    >>> import numpy as np
    >>> from driver.physics.nufft import transpose
    >>> out = np.empty((3, 2))
    >>> transpose(np.arange(6.0).reshape(2, 3), out)
    >>> out
    array([[0., 3.],
           [1., 4.],
           [2., 5.]])
    """
    scatter_columns(F, np.arange(F.shape[0], dtype=np.int64), out)


def to_fine_grid(A: np.ndarray, grid: TemporalGrid, t0_is_zero: bool,
                 columns: np.ndarray | None = None) -> np.ndarray:
    """(n_t, n_cols) coefficients (time first, as a lateral FFT of the data leaves them)
    -> (n_cols, L) values of S on the fine theta grid, one column per row.

    ``A`` is not modified. The t = 0 sample is halved when ``t0_is_zero``.

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
    ndarray ``(n_cols, grid.L)`` complex.

    Examples
    --------
    >>> import numpy as np
    >>> from driver.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
    >>> n_t, dt, c, t0 = 32, 1e-8, 1500.0, 1e-7  # samples, s, m/s, s
    >>> t = t0 + dt * np.arange(n_t)
    >>> kz = np.array([1e4, 5e4, 2e5])  # rad/m; one column with k_lat = 0: omega = c kz
    >>> grid = make_grid(n_t, "nufft", 1e-10)
    >>> to_fine_grid(np.ones((n_t, 2)), grid, t0_is_zero=False).shape  # (n_cols, L)
    (2, 64)
    """
    ctype = np.complex64 if A.dtype in (np.float32, np.complex64) else np.complex128
    cols = np.arange(A.shape[1], dtype=np.int64) if columns is None else np.asarray(columns, dtype=np.int64)
    U = np.zeros((len(cols), grid.L), dtype=ctype)
    scale = (1.0 / grid.phihat).astype(U.real.dtype)
    if t0_is_zero:
        scale = scale.copy()
        scale[0] *= 0.5
    # nufft: centred mode m = n - shift sits at fine index m mod L; FFT-grid kinds: shift 0
    _place_columns(np.ascontiguousarray(A, dtype=ctype), cols, scale, grid.shift, grid.L, U)
    scipy.fft.fft(U, axis=-1, overwrite_x=True, workers=-1)
    return U


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
    >>> from driver.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
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
    V = scipy.fft.ifft(R, axis=-1, workers=-1, norm="forward", overwrite_x=overwrite)
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
    >>> from driver.physics.nufft import group_columns
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


@numba.njit(cache=True)
def _tap_arrays(nkz, w):
    """One column group's work arrays for `_group_taps`: base (nkz,) int64, wts (w, nkz),
    t (nkz,), ar (nkz,), ai (nkz,) float64."""
    return (np.empty(nkz, np.int64), np.empty((w, nkz), np.float64), np.empty(nkz, np.float64),
            np.empty(nkz, np.float64), np.empty(nkz, np.float64))


@numba.njit(cache=True, fastmath=True)
def _group_taps(k2, kz, qw, c, dt, t0, h, kind, w, hc, shift, inversion, base, wts, t, ar, ai):
    """The taps of one column group (one |k_lat|², ``k2``) at every kz, shared by all its
    columns; returns n_j, the number of kz filled (inversion: those at or below the
    temporal Nyquist, kz ascending; otherwise all).

    Row j: ``base[j]`` the first tap's fine-grid index (before wrapping), ``wts[:, j]`` the
    w tap weights (tap-major, so that Horner's rule runs over j in SIMD lanes: the
    polynomial of tap k in ``t[j] = 2x - 1``, `kernel_polynomials`; linear: the fraction), and
    ``ar[j] + i ai[j]``
    the weight times e^{i φ_j} with φ_j = shift θ_j + ω_j t0, the centring and t0 phase of
    the +θ evaluation (its conjugate belongs to the -θ one)."""
    nkz = kz.shape[0]
    nd = hc.shape[1]
    pi_lim = math.pi * (1.0 + 1e-12)
    nj = nkz
    for j in range(nkz):
        om = c * math.sqrt(k2 + kz[j] * kz[j])
        th = om * dt
        if inversion:
            if th > pi_lim:  # kz ascending: every later one is above the Nyquist too
                nj = j
                break
            # k_z / omega, with the limit 1/c at omega = 0
            sc = qw[j] * (kz[j] / om if om > 0.0 else 1.0 / c)
        else:
            sc = qw[j]
        s = th / h
        if kind == 0:
            b = int(math.ceil(s - 0.5 * w))
            t[j] = 2.0 * (b - s + 0.5 * w) - 1.0
        elif kind == 1:
            b = int(math.floor(s))
            t[j] = s - b
        else:
            b = int(math.floor(s + 0.5))
        base[j] = b
        ph = shift * th + om * t0
        ar[j] = sc * math.cos(ph)
        ai[j] = sc * math.sin(ph)
    if kind == 0:
        for k in range(w):
            row = wts[k]
            c0 = hc[k, 0]
            for j in range(nj):
                row[j] = c0
            for d in range(1, nd):
                cd = hc[k, d]
                for j in range(nj):
                    row[j] = row[j] * t[j] + cd
    elif kind == 1:
        for j in range(nj):
            wts[0, j] = 1.0 - t[j]
            wts[1, j] = t[j]
    else:
        for j in range(nj):
            wts[0, j] = 1.0
    return nj


@numba.njit(parallel=True, cache=True, fastmath=True)
def _interp_kernel(U, gvals, gptr, order, kz, qw, c, dt, t0, h, L, kind, w, hc, shift,
                   inversion, out):
    """out[col, j] = sc_j (e^{-iφ_j} S⁺ + e^{iφ_j} S⁻): the w-tap interpolation of row
    ``U[col]`` at +θ_j and -θ_j (`_group_taps`), in real arithmetic (a complex product
    with a real weight would cost a full complex multiply)."""
    n_groups = gvals.shape[0]
    nkz = kz.shape[0]
    for g in numba.prange(n_groups):
        base, wts, t, ar, ai = _tap_arrays(nkz, w)
        nj = _group_taps(gvals[g], kz, qw, c, dt, t0, h, kind, w, hc, shift, inversion, base, wts, t, ar, ai)
        for ci in range(gptr[g], gptr[g + 1]):
            col = order[ci]
            u = U[col]
            o = out[col]
            for j in range(nj):
                b = base[j]
                p1r = 0.0
                p1i = 0.0
                p2r = 0.0
                p2i = 0.0
                if b >= 1 and b + w <= L:
                    # no wrap-around: consecutive taps at b.. and mirrored at L-b..
                    for k in range(w):
                        wk = wts[k, j]
                        v1 = u[b + k]
                        v2 = u[L - b - k]
                        p1r += wk * v1.real
                        p1i += wk * v1.imag
                        p2r += wk * v2.real
                        p2i += wk * v2.imag
                else:
                    for k in range(w):
                        wk = wts[k, j]
                        jj = (b + k) % L
                        v1 = u[jj]
                        v2 = u[(L - jj) % L]
                        p1r += wk * v1.real
                        p1i += wk * v1.imag
                        p2r += wk * v2.real
                        p2i += wk * v2.imag
                # (ar - i ai) S⁺ + (ar + i ai) S⁻
                sr = p1r + p2r
                si = p1i + p2i
                dr = p1r - p2r
                di = p1i - p2i
                o[j] = complex(ar[j] * sr + ai[j] * di, ar[j] * si - ai[j] * dr)
            for j in range(nj, nkz):
                o[j] = 0.0


@numba.njit(parallel=True, cache=True, fastmath=True)
def _spread_kernel(B, gvals, gptr, order, kz, qw, c, dt, t0, h, L, kind, w, hc, shift, R):
    """The adjoint of `_interp_kernel` (inversion False): spread B[col, j] e^{±iφ_j} qw_j
    onto the w taps at +θ_j and -θ_j of row ``R[col]``."""
    n_groups = gvals.shape[0]
    nkz = kz.shape[0]
    for g in numba.prange(n_groups):
        base, wts, t, ar, ai = _tap_arrays(nkz, w)
        _group_taps(gvals[g], kz, qw, c, dt, t0, h, kind, w, hc, shift, False, base, wts, t, ar, ai)
        # one column's fine grid accumulates in double precision (real and imaginary parts
        # interleaved), then is stored once (R of complex64 would convert on every tap)
        r = np.empty(2 * L, np.float64)
        for ci in range(gptr[g], gptr[g + 1]):
            col = order[ci]
            r[:] = 0.0
            bc = B[col]
            for j in range(nkz):
                v = bc[j]
                if v == 0:
                    continue
                vr = v.real
                vi = v.imag
                # conjugates of the interpolation phases: (ar + i ai) v at +θ, (ar - i ai) v at -θ
                ppr = ar[j] * vr - ai[j] * vi
                ppi = ar[j] * vi + ai[j] * vr
                pmr = ar[j] * vr + ai[j] * vi
                pmi = ar[j] * vi - ai[j] * vr
                b = base[j]
                if b >= 1 and b + w <= L:
                    for k in range(w):  # two loops: neither aliases itself
                        wk = wts[k, j]
                        r[2 * (b + k)] += wk * ppr
                        r[2 * (b + k) + 1] += wk * ppi
                    for k in range(w):
                        wk = wts[k, j]
                        r[2 * (L - b - k)] += wk * pmr
                        r[2 * (L - b - k) + 1] += wk * pmi
                else:
                    for k in range(w):
                        wk = wts[k, j]
                        jj = (b + k) % L
                        jm = (L - jj) % L
                        r[2 * jj] += wk * ppr
                        r[2 * jj + 1] += wk * ppi
                        r[2 * jm] += wk * pmr
                        r[2 * jm + 1] += wk * pmi
            out = R[col]
            for i in range(L):
                out[i] = complex(r[2 * i], r[2 * i + 1])


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
    out_dtype=None,
    progress=None,
    n_chunks: int = 8,
    groups: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Evaluate the even-extended transform of every column at omega = c |k|.

    U : (n_cols, L) from `to_fine_grid`. klat2 : (n_cols,) |k_lat|^2 in rad^2/m^2.
    kz : (n_kz,) depth wavenumbers in rad/m (ascending when inversion). qw : (n_kz,) weights per kz.
    inversion=True multiplies by qw * kz/omega (1/c at omega = 0) and zeroes omega above
    the temporal Nyquist pi/dt (DESIGN §3.1); False multiplies by qw only.
    progress: optional callable(fraction in (0, 1]) called after each of up to ``n_chunks``
    chunks of column groups (fewer for small transforms).
    groups: `group_columns` (klat2) when the caller keeps it (an operator applied many
    times); None: computed here.
    Returns (n_cols, n_kz) complex.

    Parameters
    ----------
    U : ndarray ``(n_cols, L)`` from :func:`to_fine_grid`.
    grid : TemporalGrid.
    klat2 : ndarray ``(n_cols,)``, |k_lat|² in rad²/m².
    kz : ndarray ``(n_kz,)``, depth wavenumbers in rad/m.
    qw : ndarray ``(n_kz,)``, weights per kz.
    c : float, m/s.  dt : float, s.  t0 : float, s (time of sample 0).
    inversion : bool, see above.
    out_dtype, progress, n_chunks, groups
        See above.

    Returns
    -------
    ndarray ``(n_cols, n_kz)`` complex.

    Raises
    ------
    ValueError
        ``inversion`` with kz not ascending.

    References
    ----------
    .. [1] K. Fourmont, "Non-equispaced fast Fourier transforms with applications to
       tomography", J. Fourier Anal. Appl. 9 (2003).

    Examples
    --------
    The transform of the evenly extended series, E(ω) = Σ_n a_n 2 cos(ω t_n), against the
    direct sum:

    >>> import numpy as np
    >>> from driver.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
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
    out = np.empty((U.shape[0], len(kz)), dtype=out_dtype or U.dtype)
    kz = np.asarray(kz, np.float64)
    qw = np.asarray(qw, np.float64)
    if inversion and np.any(np.diff(kz) < 0):
        raise ValueError("kz must be ascending for the inversion (every kz after the first above the Nyquist is too)")
    for a, b in _group_chunks(len(gvals), n_chunks, U.shape[0] * len(kz), progress):
        _interp_kernel(U, gvals[a:b], gptr[a : b + 1], order, kz, qw, float(c), float(dt), float(t0),
                       2.0 * np.pi / grid.L, grid.L, _KIND_CODE[grid.kind], grid.w, grid.horner,
                       grid.shift, bool(inversion), out)
    return out


def _group_chunks(n_groups: int, n_chunks: int, work: int, progress=None):
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
    progress=None,
    n_chunks: int = 1,
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

    Returns
    -------
    ndarray ``(n_cols, grid.L)`` complex.

    Examples
    --------
    The adjoint identity <evaluate(a), b> = <a, from_fine_grid(spread(b))>:

    >>> import numpy as np
    >>> from driver.physics.nufft import evaluate, from_fine_grid, make_grid, spread, to_fine_grid
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
    R = np.zeros((B.shape[0], grid.L), dtype=ctype)
    kz = np.asarray(kz, np.float64)
    qw = np.asarray(qw, np.float64)
    for a, b in _group_chunks(len(gvals), n_chunks, B.shape[0] * len(kz), progress):
        _spread_kernel(B, gvals[a:b], gptr[a : b + 1], order, kz, qw, float(c), float(dt), float(t0),
                       2.0 * np.pi / grid.L, grid.L, _KIND_CODE[grid.kind], grid.w, grid.horner, grid.shift, R)
    return R
