"""The sizes the transforms work on, chosen without loading them: the width of the temporal
NUFFT's ES kernel for a tolerance and the fine-grid length L of a series (`fpscan.physics.nufft`
plans and runs the transform on it), and the zero-padded working grid of the free-space model
(`fpscan.physics.forward`, `fpscan.service.recon.operator`). Pure Python (``math`` and the
fast-length rule): the memory model of a job (`fpscan.service.recon.checks`) sizes its arrays from
here on the server's request path without loading numba or scipy.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

from fpscan.physics.fast_lengths import fast_dct1_rows, fast_length

__all__ = ["KINDS", "kernel_params", "grid_length", "pad_sizes"]

#: the temporal transforms: the NUFFT, or the DFT of the mirrored series + interpolation
KINDS = ("nufft", "linear", "nearest")


def kernel_params(eps: float) -> tuple[int, float]:
    """Width w (taps) and shape beta of the ES kernel for tolerance ``eps`` at
    oversampling 2 (FINUFFT's rule).

    Parameters
    ----------
    eps : float in [1e-14, 1e-1], the relative tolerance of the transform.

    Returns
    -------
    w : int, taps (2..16).
    beta : float, the kernel's shape parameter.

    Raises
    ------
    ValueError
        ``eps`` outside [1e-14, 1e-1].

    References
    ----------
    .. [1] A. H. Barnett, J. Magland, L. af Klinteberg, "A parallel nonuniform fast Fourier
       transform library based on an 'exponential of semicircle' kernel", SIAM J. Sci.
       Comput. 41 (2019), §4.

    Examples
    --------
    >>> from fpscan.physics.grid_sizes import kernel_params
    >>> w, beta = kernel_params(1e-6)
    >>> w, round(beta, 2)
    (7, 16.1)
    """
    if not (1e-14 <= eps <= 1e-1):
        raise ValueError(f"eps must be in [1e-14, 1e-1], got {eps}")
    w = int(math.ceil(-math.log10(eps / 10.0)))
    w = max(2, min(w, 16))
    beta_over_w = {2: 2.20, 3: 2.26, 4: 2.38}.get(w, 2.30)
    return w, beta_over_w * w


def grid_length(n_t: int, kind: str = "nufft", eps: float = 1e-6) -> int:
    """L, the fine-grid FFT length `make_grid` plans for series of ``n_t`` samples: the
    oversampled grid L >= 2 M (nufft, even) or the DFT grid of the mirrored series
    L >= 2 n_t - 1 (linear, nearest), rounded up to a fast length
    (`fpscan.physics.fast_lengths`; S is sampled exactly on any grid of L >= n_t points,
    a finer one only interpolates better).

    Parameters
    ----------
    n_t : int >= 1, samples per series.
    kind : one of ``KINDS``.
    eps : float, tolerance of the nufft kind (:func:`kernel_params`).

    Returns
    -------
    int, samples.

    Raises
    ------
    ValueError
        A bad kind, n_t or eps.

    Examples
    --------
    >>> from fpscan.physics.grid_sizes import grid_length
    >>> grid_length(100), grid_length(100, "linear")  # 2 M = 200; 2 n_t - 1 = 199 -> fast 200
    (200, 200)
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    n_t = int(n_t)
    if n_t < 1:
        raise ValueError("n_t must be >= 1")
    if kind == "nufft":
        w, _ = kernel_params(eps)
        return fast_length(max(2 * (n_t + (n_t % 2)), 2 * w + 2), even=True)
    return fast_length(2 * n_t - 1) if n_t > 1 else 2


def pad_sizes(shape: Sequence[int], dx: float, dz: float, dt: float, n_t: int, c: float, t0: float,
              extra_lateral: float = 0.0) -> tuple[int, int, int]:
    """Zero-padded working grid (N_z, N_y, N_x) >= shape of the free-space model: no periodic
    image reaches a sensor within the record. Every length is rounded up to a fast one
    (`fpscan.physics.fast_lengths`; more padding only moves the periodic images further
    away): the depth DCT-I's 2 (N_z - 1), y's complex and x's real FFT; N_y - n_y and
    N_x - n_x stay even so that the image sits centred; N_y = N_x (both real fast
    lengths) where that pads at most 15 % more.

    The rule is the tight one for an image whose rows start at the sensor plane. Lateral:
    the nearest periodic image of a source lies N dx - (n - 1) dx beyond the farthest
    sensor of the aperture (plus ``extra_lateral`` for sensors outside it), and a source
    in row 0 is heard at lateral offset r at time r / c, so that gap must exceed the
    record's reach c (t0 + (n_t - 1) dt); a deeper source (depth z) is heard later,
    sqrt(z² + r²) / c, so row 0 sets the bound. Depth: the DCT-I's period 2 (N_z - 1) dz
    puts the nearest non-physical image of a source at depth z at 2 (N_z - 1) dz - z,
    hence 2 (N_z - 1) dz >= reach + (n_z - 1) dz. The reach adds half a sample and two
    pitches laterally (max(dx, dz)) and one in depth (dz): the band-limited interpolant of a voxel
    is not compactly supported.

    Parameters
    ----------
    shape : tuple of int
        The image ``(n_z, n_y, n_x)`` (``n_y`` = 1 for a 2-D image).
    dx, dz : float
        Lateral and depth pitch, m.
    dt : float
        Sample interval, s.
    n_t : int
        Samples per A-line.
    c : float
        Sound speed, m/s.
    t0 : float
        Time of sample 0, s.
    extra_lateral : float, optional
        How far sensors lie beyond the image's lateral extent, m (both sides together).

    Returns
    -------
    tuple of int
        ``(N_z, N_y, N_x)``, each >= the image's.

    Examples
    --------
    >>> from fpscan.physics.grid_sizes import pad_sizes
    >>> pad_sizes((256, 128, 128), 60e-6, 12e-6, 8e-9, 256, 1500.0, 0.0)  # the record reaches 51 pitches
    (257, 192, 192)
    """
    n_z, n_y, n_x = shape
    record = c * (t0 + (n_t - 0.5) * dt)
    reach = record + 2 * max(dx, dz)
    depth = (n_z - 1) * dz
    # 2 (N_z - 1) dz >= the record's reach + one depth pitch + the image's depth
    k_min = int(math.ceil((record + dz + depth) / (2 * dz))) + 1
    n_z2 = fast_dct1_rows(max(n_z, k_min))

    def lateral(n: int, is_singleton: bool, real: bool, at_least: int = 1) -> int:
        if is_singleton:
            return n
        need = (n - 1) * dx + extra_lateral + reach
        n2 = fast_length(max(n, at_least, int(math.ceil(need / dx)) + 1), real=real)
        while (n2 - n) % 2:
            n2 = fast_length(n2 + 1, real=real)
        return n2

    n_y2, n_x2 = lateral(n_y, n_y == 1, False), lateral(n_x, False, True)
    if n_y > 1 and (n_y - n_x) % 2 == 0:
        # one length for both axes when it pads little more (<= 15 %): k_x and k_y then take
        # the same values, so columns of equal |k_lat| group four- to eightfold and the
        # temporal step computes its taps once per group (as `fpscan.service.recon.planar`)
        common = lateral(n_x, False, True, at_least=max(n_y2, n_x2))
        if common <= 1.15 * max(n_y2, n_x2):
            n_y2 = n_x2 = common
    return n_z2, n_y2, n_x2
