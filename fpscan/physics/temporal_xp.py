"""The temporal step of planar PAT on any array namespace: NumPy on the CPU, CuPy on a GPU.

The same transform as `fpscan.physics.nufft` (its module doc has the formulas: the even-extended
series' transform E(ω) = Σ_n a_n 2 cos(ω t_n) at ω = c |k| of every k-space column, as a 1-D
type-2 NUFFT with FINUFFT's "exponential of semicircle" kernel, and its adjoint), written once
with the operations NumPy and CuPy share (``xp``: the array module, ``numpy`` or ``cupy``): the
GPU path (`fpscan.service.recon.gpu`) runs it on CuPy, and the tests run the same code on NumPy against
the CPU's compiled kernels (`tests/recon/test_gpu_path_on_numpy.py`: 1e-12 in float64), so a
change to either shows there. The taps are computed on ``xp`` per column group (columns of equal
|k_lat|² share them, `fpscan.physics.nufft.group_columns`) in float64 with the polynomials of
`fpscan.physics.nufft.kernel_polynomials`; the sums run one tap at a time over every column and
kz together (memory: a few (n_cols, n_kz) arrays, never (n_cols, n_kz, w)).

Only the ``"nufft"`` kind (NER) is here: the k-Wave-style interpolations stay on the CPU.

Functions take and return arrays of ``xp``; shapes are (n_cols, ...) with one k-space column
per row, as `fpscan.physics.nufft` orders them.
"""
from __future__ import annotations

from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from fpscan.physics.nufft import TemporalGrid, group_columns, group_tap_arrays

__all__ = ["Taps", "taps", "evaluate", "spread", "to_fine_grid", "from_fine_grid", "dct1"]


class Taps(NamedTuple):
    """The interpolation taps of one temporal transform (made by :func:`taps`), on ``xp``.

    Attributes
    ----------
    base : array ``(n_cols, n_kz)`` int64
        Each evaluation's first tap's fine-grid index, before wrapping modulo ``L``.
    weights : array ``(w, n_groups, n_kz)``
        Tap weights per column group (the working real dtype).
    phase : array ``(n_groups, n_kz)`` complex
        ``qw`` (times k_z/ω and the Nyquist cut for an inversion) times e^{iφ},
        φ = shift θ + ω t0: the phase of the +θ evaluation (its conjugate is the -θ one's).
    group : array ``(n_cols,)`` int64
        Each column's group.
    L : int
        Fine-grid length.
    """

    base: Any
    weights: Any
    phase: Any
    group: Any
    L: int


def taps(xp: ModuleType, grid: TemporalGrid, klat2: np.ndarray, kz: np.ndarray, qw: np.ndarray, c: float,
         dt: float, t0: float, inversion: bool, real_dtype: Any) -> Taps:
    """The taps of `evaluate` / `spread` for columns of |k_lat|² ``klat2``, on ``xp``.

    `fpscan.physics.nufft.group_tap_arrays` per column group (the compiled kernels' formulas,
    in float64), the weights and phases then cast to ``real_dtype``'s precision.

    Parameters
    ----------
    xp : module
        ``numpy`` or ``cupy``.
    grid : TemporalGrid
        Of kind ``"nufft"`` (`fpscan.physics.nufft.make_grid`).
    klat2 : ndarray ``(n_cols,)``
        |k_lat|² per column, rad²/m² (host array).
    kz, qw : ndarray ``(n_kz,)``
        Depth wavenumbers (rad/m; ascending for an inversion) and their quadrature weights.
    c, dt, t0 : float
        Sound speed (m/s), sample interval and time of sample 0 (s).
    inversion : bool
        Multiply by k_z/ω (1/c at ω = 0) and zero every kz from the first above the temporal
        Nyquist π/dt on (the inversion's weight: the paper, eq. (1)); else by ``qw`` only.
    real_dtype : dtype
        float32 or float64: the precision of the weights and phases.

    Returns
    -------
    Taps

    Raises
    ------
    ValueError
        A grid of another kind than ``"nufft"``; kz not ascending for an inversion.
    """
    if grid.kind != "nufft":
        raise ValueError(f"the array-namespace temporal step runs the 'nufft' kind only, got {grid.kind!r}")
    kz_h = np.asarray(kz, np.float64)
    if inversion and np.any(np.diff(kz_h) < 0):
        raise ValueError("kz must be ascending for the inversion")
    gvals_h, gptr, order = group_columns(klat2)
    group_h = np.empty(len(order), np.int64)
    group_h[order] = np.repeat(np.arange(len(gvals_h)), np.diff(gptr))
    base, weights, ar, ai = group_tap_arrays(xp, grid, xp.asarray(gvals_h), xp.asarray(kz_h),
                                              xp.asarray(np.asarray(qw, np.float64)), c, dt, t0, inversion)
    rdtype = np.dtype(real_dtype)
    phase = (ar + 1j * ai).astype(np.result_type(rdtype, np.complex64))
    del ar, ai
    group = xp.asarray(group_h)
    return Taps(base.astype(np.int64)[group], weights.astype(rdtype), phase, group, grid.L)


def evaluate(xp: ModuleType, U: Any, tp: Taps) -> Any:
    """E at every column's ω (`fpscan.physics.nufft.evaluate`): ``U`` ``(n_cols, L)`` from
    :func:`to_fine_grid` -> ``(n_cols, n_kz)`` complex, weighted as ``tp`` says.

    Parameters
    ----------
    xp : module
        ``numpy`` or ``cupy``.
    U : array ``(n_cols, L)`` complex
        The fine-grid values of every column.
    tp : Taps
        From :func:`taps` for these columns.

    Returns
    -------
    array ``(n_cols, n_kz)`` of U's dtype.
    """
    L = tp.L
    p1 = xp.zeros(tp.base.shape, dtype=U.dtype)  # S(+θ)
    p2 = xp.zeros(tp.base.shape, dtype=U.dtype)  # S(-θ)
    for k in range(tp.weights.shape[0]):
        idx = (tp.base + k) % L
        wk = tp.weights[k][tp.group]
        p1 += wk * xp.take_along_axis(U, idx, axis=1)
        idx = (L - idx) % L
        p2 += wk * xp.take_along_axis(U, idx, axis=1)
    e = tp.phase[tp.group]
    return xp.conj(e) * p1 + e * p2


def spread(xp: ModuleType, B: Any, tp: Taps) -> Any:
    """The adjoint of :func:`evaluate` (`fpscan.physics.nufft.spread`): ``B`` ``(n_cols, n_kz)``
    complex -> ``(n_cols, L)`` spread fine-grid values (input of :func:`from_fine_grid`).

    Each tap adds w e B at +θ and w ē B at -θ; the sums are scatter-adds (NumPy:
    ``bincount`` in float64; CuPy: ``cupy.add.at``, atomic, in the working precision).

    Parameters
    ----------
    xp : module
        ``numpy`` or ``cupy``.
    B : array ``(n_cols, n_kz)`` complex
    tp : Taps

    Returns
    -------
    array ``(n_cols, L)`` of B's dtype.
    """
    n_cols, L = B.shape[0], tp.L
    rdtype = B.real.dtype
    e = tp.phase[tp.group]
    plus, minus = e * B, xp.conj(e) * B
    flat = xp.zeros(n_cols * L * 2, dtype=rdtype)  # (re, im) pairs of R, row after row
    row0 = (xp.arange(n_cols, dtype=np.int64) * (2 * L))[:, None]
    for k in range(tp.weights.shape[0]):
        idx = (tp.base + k) % L
        wk = tp.weights[k][tp.group]
        for where, vals in ((idx, plus), ((L - idx) % L, minus)):
            at = row0 + 2 * where
            _scatter_add(xp, flat, at, wk * vals.real)
            _scatter_add(xp, flat, at + 1, wk * vals.imag)
    return flat.view(B.dtype).reshape(n_cols, L)


def _scatter_add(xp: ModuleType, flat: Any, index: Any, values: Any) -> None:
    """flat[index] += values, repeated indices summed (NumPy: one ``bincount`` in float64;
    CuPy: ``cupy.add.at``, atomic adds)."""
    if xp is np:
        flat += np.bincount(index.ravel(), weights=values.ravel(), minlength=flat.size).astype(flat.dtype)
        return
    xp.add.at(flat, index.ravel(), values.ravel().astype(flat.dtype))


def _scale(xp: ModuleType, grid: TemporalGrid, t0_is_zero: bool, rdtype: Any) -> Any:
    """1 / φ̂ per sample (the deconvolution), sample 0 halved when it is at t = 0."""
    scale = 1.0 / np.asarray(grid.phihat, np.float64)
    if t0_is_zero:
        scale = scale.copy()
        scale[0] *= 0.5
    return xp.asarray(scale.astype(rdtype))


def to_fine_grid(xp: ModuleType, a: Any, grid: TemporalGrid, t0_is_zero: bool) -> Any:
    """``a`` ``(n_cols, n_t)`` (one series per row) -> ``(n_cols, L)`` values of S on the
    fine θ grid (`fpscan.physics.nufft.to_fine_grid`, which takes its series as columns).

    Parameters
    ----------
    xp : module
    a : array ``(n_cols, n_t)`` complex (complex64 stays single precision)
    grid : TemporalGrid of ``n_t``, kind ``"nufft"``
    t0_is_zero : bool
        Sample 0 is at t = 0 (its weight is halved).

    Returns
    -------
    array ``(n_cols, L)`` complex.
    """
    n_cols, n_t = a.shape
    ctype = np.result_type(a.dtype, np.complex64)
    U = xp.zeros((n_cols, grid.L), dtype=ctype)
    at = xp.asarray((np.arange(n_t) - grid.shift) % grid.L)
    U[:, at] = a * _scale(xp, grid, t0_is_zero, U.real.dtype)[None, :]
    return xp.fft.fft(U, axis=-1)


def from_fine_grid(xp: ModuleType, R: Any, grid: TemporalGrid, t0_is_zero: bool) -> Any:
    """The adjoint of :func:`to_fine_grid`: ``R`` ``(n_cols, L)`` -> ``(n_cols, n_t)``
    (`fpscan.physics.nufft.from_fine_grid`).

    Parameters
    ----------
    xp : module
    R : array ``(n_cols, L)`` complex (from :func:`spread`)
    grid : TemporalGrid
    t0_is_zero : bool

    Returns
    -------
    array ``(n_cols, n_t)`` complex.
    """
    V = xp.fft.ifft(R, axis=-1, norm="forward")
    at = xp.asarray((np.arange(grid.n_t) - grid.shift) % grid.L)
    return V[:, at] * _scale(xp, grid, t0_is_zero, V.real.dtype)[None, :]


def dct1(xp: ModuleType, x: Any, axis: int = -1) -> Any:
    """The unnormalised DCT-I along ``axis`` (scipy's type 1: y_k = x_0 + (-1)^k x_{N-1} +
    2 Σ_{n=1}^{N-2} x_n cos(π k n / (N - 1))), of real or complex ``x``, as the FFT of its even
    extension (length 2 (N - 1)), whose sine terms cancel exactly.

    Parameters
    ----------
    xp : module
    x : array, N >= 2 along ``axis``
    axis : int

    Returns
    -------
    array of x's shape; complex for complex x, real for real x.

    Raises
    ------
    ValueError
        Fewer than 2 samples along ``axis``.
    """
    x = xp.moveaxis(x, axis, -1)
    if x.shape[-1] < 2:
        raise ValueError("the DCT-I needs at least 2 samples")
    ext = xp.concatenate([x, x[..., -2:0:-1]], axis=-1)
    y = xp.fft.fft(ext, axis=-1)[..., : x.shape[-1]]
    if not xp.iscomplexobj(x):
        y = y.real
    return xp.moveaxis(y, -1, axis)
